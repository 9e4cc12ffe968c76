// @brief The oracle for core/io/png_encoder.h: libpng's own writer at its
// default settings, which the encoder must match byte for byte.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/io/png_encoder.h"

namespace nimbus::testing {

/// `samples` (host order, shape.RowBytes() per row, rows top first)
/// encoded by libpng with nothing changed but the byte order of 16-bit
/// samples. Empty when libpng fails.
std::string LibpngEncode(const PngShape& shape, const std::vector<uint8_t>& samples);

}  // namespace nimbus::testing
