// A job's view names its main result file with its format's extension.
#include "server/job_view.h"

#include <gtest/gtest.h>

namespace nimbus::server {
namespace {

JobRecord Succeeded(const v1::JobSpec& spec) {
  JobRecord r;
  r.id = "j-1";
  r.name = "arcs";
  r.state = JobState::kSucceeded;
  r.spec = spec.SerializeAsString();
  return r;
}

TEST(JobView, MainResultFileNameHasItsFormatsExtension) {
  v1::JobSpec volume;
  volume.mutable_chaos_game();
  volume.mutable_image()->set_width(64);
  EXPECT_EQ(ToProto(Succeeded(volume), false).result().file_name(), "arcs.vdb");
  v1::JobSpec picture = volume;
  picture.mutable_image()->set_image_only(true);
  EXPECT_EQ(ToProto(Succeeded(picture), false).result().file_name(), "arcs.png");
  picture.mutable_image()->set_format(v1::IMAGE_FORMAT_EXR);
  EXPECT_EQ(ToProto(Succeeded(picture), true).result().file_name(), "arcs.exr");
  v1::JobSpec explore;
  explore.mutable_explore();
  EXPECT_EQ(ToProto(Succeeded(explore), false).result().file_name(), "arcs.png");
}

}  // namespace
}  // namespace nimbus::server
