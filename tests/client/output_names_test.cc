// `nimbus render -o` and `nimbus fetch -o` never give a file another
// format's extension.
#include "client/output_names.h"

#include <gtest/gtest.h>

namespace nimbus::client {
namespace {

v1::JobSpec VolumeWithPicture(v1::ImageFormat format) {
  v1::JobSpec spec;
  spec.mutable_chaos_game();
  spec.mutable_image()->set_width(64);
  spec.mutable_image()->set_format(format);
  return spec;
}

TEST(MainOutputPath, AVolumeKeepsAVdbNameOrNone) {
  v1::JobSpec spec;
  spec.mutable_chaos_game();
  EXPECT_EQ(MainOutputPath("out/tree.vdb", spec).value_or(""), "out/tree.vdb");
  EXPECT_EQ(MainOutputPath("out/tree", spec).value_or(""), "out/tree");
  EXPECT_EQ(MainOutputPath("out/tree.VDB", spec).value_or(""), "out/tree.VDB");
}

TEST(MainOutputPath, ThePictureNameOfAVolumeJobPutsTheVolumeBesideIt) {
  EXPECT_EQ(MainOutputPath("out/arcs.png", VolumeWithPicture(v1::IMAGE_FORMAT_PNG16)).value_or(""),
            "out/arcs.vdb");
  EXPECT_EQ(MainOutputPath("arcs.exr", VolumeWithPicture(v1::IMAGE_FORMAT_EXR)).value_or(""),
            "arcs.vdb");
}

TEST(MainOutputPath, AnotherFormatsExtensionIsRefusedNamingOutput) {
  auto png_on_exr = MainOutputPath("out/arcs.png", VolumeWithPicture(v1::IMAGE_FORMAT_EXR));
  ASSERT_EQ(png_on_exr.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(png_on_exr.status().message(),
            "-o out/arcs.png: this job's main result is an OpenVDB volume, not a .png file; "
            "name it out/arcs.vdb (its picture is written beside it as out/arcs.exr)");
  v1::JobSpec picture_only = VolumeWithPicture(v1::IMAGE_FORMAT_PNG8);
  picture_only.mutable_image()->set_image_only(true);
  EXPECT_EQ(MainOutputPath("a.png", picture_only).value_or(""), "a.png");
  auto vdb = MainOutputPath("a.vdb", picture_only);
  EXPECT_EQ(vdb.status().message(),
            "-o a.vdb: this job's main result is a PNG picture, not a .vdb file; name it a.png");
  v1::JobSpec explore;
  explore.mutable_explore();
  EXPECT_FALSE(MainOutputPath("sheet.vdb", explore).ok());
  v1::JobSpec volume;
  volume.mutable_chaos_game();
  EXPECT_FALSE(MainOutputPath("tree.png", volume).ok());
}

TEST(CheckOutputExtension, FetchNamesTheFileItsOwnFormat) {
  EXPECT_TRUE(CheckOutputExtension("x.vdb", "tree.vdb").ok());
  EXPECT_TRUE(CheckOutputExtension("x", "tree.vdb").ok());
  EXPECT_TRUE(CheckOutputExtension("x.PNG", "arcs.png").ok());
  const absl::Status s = CheckOutputExtension("d/x.vdb", "arcs.png");
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(s.message(), "-o d/x.vdb: the file is arcs.png; name it d/x.png");
}

}  // namespace
}  // namespace nimbus::client
