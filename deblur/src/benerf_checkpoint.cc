#include "benerf_checkpoint.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "evkit/base/error.h"

namespace evkit::benerf_detail {

namespace {

constexpr char kCheckpointMagic[8] = {'E', 'V', 'K', 'B', 'N', 'R', 'F', '1'};

}  // namespace

void writeCheckpoint(const std::string& path, const Checkpoint& c,
                     nerf::RadianceField<float>& field, const Trajectory& trajectory,
                     const nerf::Adam<float>& field_adam, const nerf::Adam<double>& knot_adam,
                     const std::mt19937_64& rng) {
  const std::string tmp = path + ".partial";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw Error(path + ": cannot write the checkpoint");
    out.write(kCheckpointMagic, sizeof(kCheckpointMagic));
    out.write(reinterpret_cast<const char*>(&c), sizeof(c));
    for (const nerf::ParameterBlock<float>& b : field.parameters()) {
      const uint64_t n = b.size;
      out.write(reinterpret_cast<const char*>(&n), sizeof(n));
      out.write(reinterpret_cast<const char*>(b.values),
                static_cast<std::streamsize>(b.size * sizeof(float)));
    }
    for (const SE3& k : trajectory.knots()) {
      const double v[7] = {k.rotation().w(),   k.rotation().x(),    k.rotation().y(),
                           k.rotation().z(),   k.translation().x(), k.translation().y(),
                           k.translation().z()};
      out.write(reinterpret_cast<const char*>(v), sizeof(v));
    }
    field_adam.save(out);
    knot_adam.save(out);
    std::ostringstream state;
    state << rng;
    const std::string text = state.str();
    const uint64_t n = text.size();
    out.write(reinterpret_cast<const char*>(&n), sizeof(n));
    out.write(text.data(), static_cast<std::streamsize>(n));
    if (!out) throw Error(path + ": cannot write the checkpoint");
  }
  std::filesystem::rename(tmp, path);
}

Checkpoint readCheckpoint(const std::string& path, nerf::RadianceField<float>& field,
                          Trajectory& trajectory, nerf::Adam<float>& field_adam,
                          nerf::Adam<double>& knot_adam, std::mt19937_64& rng) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open the checkpoint");
  char magic[8];
  in.read(magic, sizeof(magic));
  if (!in || !std::equal(magic, magic + 8, kCheckpointMagic))
    throw Error(path + ": not an evkit BeNeRF checkpoint");
  Checkpoint c;
  in.read(reinterpret_cast<char*>(&c), sizeof(c));
  for (const nerf::ParameterBlock<float>& b : field.parameters()) {
    uint64_t n = 0;
    in.read(reinterpret_cast<char*>(&n), sizeof(n));
    if (!in || n != b.size)
      throw Error(path + ": the checkpoint's field does not match these settings (byte " +
                  std::to_string(static_cast<long long>(in.tellg())) + ")");
    in.read(reinterpret_cast<char*>(b.values),
            static_cast<std::streamsize>(b.size * sizeof(float)));
  }
  for (SE3& k : trajectory.knots()) {
    double v[7];
    in.read(reinterpret_cast<char*>(v), sizeof(v));
    k = SE3(Quaternion(v[0], v[1], v[2], v[3]), Vector3(v[4], v[5], v[6]));
  }
  field_adam.restore(in);
  knot_adam.restore(in);
  uint64_t n = 0;
  in.read(reinterpret_cast<char*>(&n), sizeof(n));
  if (!in || n > 100000) throw Error(path + ": truncated checkpoint");
  std::string text(n, '\0');
  in.read(text.data(), static_cast<std::streamsize>(n));
  if (!in) throw Error(path + ": truncated checkpoint");
  std::istringstream state(text);
  state >> rng;
  return c;
}

}  // namespace evkit::benerf_detail
