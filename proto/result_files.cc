#include "proto/result_files.h"

#include "core/io/image_io.h"

namespace nimbus::spec {

namespace {

const char* PictureExtension(const v1::ImageOutput& image) {
  return ImageExtension(image.format() == v1::IMAGE_FORMAT_EXR ? ImageFormat::kExr
                                                               : ImageFormat::kPng8);
}

}  // namespace

std::string MainResultExtension(const v1::JobSpec& spec) {
  if (spec.has_explore()) return ".png";
  if (spec.has_image() && spec.image().image_only()) return PictureExtension(spec.image());
  return ".vdb";
}

std::string SidePictureExtension(const v1::JobSpec& spec) {
  if (spec.has_explore() || !spec.has_image() || spec.image().image_only()) return "";
  return PictureExtension(spec.image());
}

}  // namespace nimbus::spec
