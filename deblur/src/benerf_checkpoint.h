// BeNeRF checkpoints: the field, the knots, both optimisers' moments and the random state, so
// that a stopped run resumes bit for bit.
#pragma once

#include <random>
#include <string>

#include "evkit/nerf/adam.h"
#include "evkit/nerf/field.h"
#include "evkit/spline/trajectory.h"

namespace evkit::benerf_detail {

struct Checkpoint {
  int iteration = 0;
  int iterations = 0;
  int views = 0;
};

// Written to "<path>.partial", then renamed.
void writeCheckpoint(const std::string& path, const Checkpoint& c,
                     nerf::RadianceField<float>& field, const Trajectory& trajectory,
                     const nerf::Adam<float>& field_adam, const nerf::Adam<double>& knot_adam,
                     const std::mt19937_64& rng);
// Throws evkit::Error when the file is not a checkpoint or does not match the field's size.
Checkpoint readCheckpoint(const std::string& path, nerf::RadianceField<float>& field,
                          Trajectory& trajectory, nerf::Adam<float>& field_adam,
                          nerf::Adam<double>& knot_adam, std::mt19937_64& rng);

}  // namespace evkit::benerf_detail
