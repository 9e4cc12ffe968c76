// The file formats of a job's results, read from its spec: what a client
// names the files it downloads and what a job's view reports.
#pragma once

#include <string>

#include "nimbus/v1/spec.pb.h"

namespace nimbus::spec {

/// The extension of the main result file of a job running `spec`: ".png"
/// for an explore contact sheet, the picture's (".png" or ".exr") for an
/// image-only job, ".vdb" otherwise.
std::string MainResultExtension(const v1::JobSpec& spec);

/// The extension of the picture a job writes beside its volume (the
/// further file NAME.png or NAME.exr); empty when it writes none.
std::string SidePictureExtension(const v1::JobSpec& spec);

}  // namespace nimbus::spec
