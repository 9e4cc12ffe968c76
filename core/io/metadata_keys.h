// @brief The names of the metadata Nimbus writes into its VDB files, in one
// place, so writers, readers and tests agree (README, "What the .vdb
// contains").
#pragma once

namespace nimbus::meta_key {

// Every result.
inline constexpr char kSpecHash[] = "nimbus_spec_hash";
inline constexpr char kVersion[] = "nimbus_version";
inline constexpr char kSeed[] = "nimbus_seed";
inline constexpr char kIterations[] = "nimbus_iterations";
// Every grid: output conventions (docs/dcc.md).
inline constexpr char kUpAxis[] = "nimbus_up_axis";
inline constexpr char kDownsampleFactor[] = "nimbus_downsample_factor";
// The density grid: a shader density multiplier for DCC importers.
inline constexpr char kSuggestedDensity[] = "nimbus_suggested_density";
// Previews: the server's sequence number and the work done it shows.
inline constexpr char kPreviewSequence[] = "nimbus_preview_sequence";
inline constexpr char kPreviewDone[] = "nimbus_preview_done";
// Chaos games.
inline constexpr char kOutside[] = "nimbus_outside";
inline constexpr char kReseeded[] = "nimbus_reseeded";
inline constexpr char kFinalNonfinite[] = "nimbus_final_nonfinite";
inline constexpr char kStopReason[] = "nimbus_stop_reason";
inline constexpr char kCountScale[] = "nimbus_count_scale";
inline constexpr char kConvergenceChange[] = "nimbus_convergence_change";
// IFS matrices.
inline constexpr char kComponents[] = "nimbus_components";
// Set IFS.
inline constexpr char kWarmup[] = "nimbus_warmup";
inline constexpr char kBookAddress[] = "nimbus_book_address";
inline constexpr char kBookPage[] = "nimbus_book_page";
inline constexpr char kBookDepth[] = "nimbus_book_depth";
inline constexpr char kBookPages[] = "nimbus_book_pages";
// Fractal fields.
inline constexpr char kFieldDimensions[] = "nimbus_field_dimensions";
inline constexpr char kFieldMeshes[] = "nimbus_field_meshes";
inline constexpr char kFieldInterpolation[] = "nimbus_field_interpolation";
inline constexpr char kFieldFrame[] = "nimbus_field_frame";
inline constexpr char kFieldTime[] = "nimbus_field_time";
inline constexpr char kFieldOutput[] = "nimbus_field_output";
// Jelly frames.
inline constexpr char kJellyFrame[] = "nimbus_jelly_frame";
inline constexpr char kJellyTime[] = "nimbus_jelly_time";
inline constexpr char kJellyLeaves[] = "nimbus_jelly_leaves";
inline constexpr char kJellyPokes[] = "nimbus_jelly_pokes";

}  // namespace nimbus::meta_key
