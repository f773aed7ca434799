#include <gtest/gtest.h>
#include <omp.h>

#include <cmath>
#include <memory>
#include <random>
#include <stdexcept>

#include "evkit/nerf/adam.h"
#include "evkit/nerf/camera.h"
#include "evkit/nerf/field.h"
#include "evkit/nerf/ray_batch.h"
#include "evkit/nerf/train.h"
#include "evkit/nerf/volume_render.h"
#include "evkit/synth/generator.h"
#include "jacobian_check.h"

namespace evkit::nerf {
namespace {

using MatrixD = Eigen::MatrixXd;
constexpr double kEps = 1e-6;
constexpr double kTol = 1e-6;  // relative, against central differences in double

Eigen::VectorXd flat(const MatrixD& m) {
  return Eigen::Map<const Eigen::VectorXd>(m.data(), m.size());
}

TEST(VolumeRender, BackwardAgainstCentralDifferences) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  for (int channels : {1, 3}) {
    for (double scale : {0.1, 3.0, 40.0}) {
      const size_t n = 12;
      Eigen::VectorXd x(static_cast<Eigen::Index>(n * (1 + channels)));  // sigma then colours
      for (Eigen::Index i = 0; i < x.size(); ++i)
        x(i) = i < static_cast<Eigen::Index>(n) ? scale * u(rng) : u(rng);
      std::vector<double> delta(n);
      for (double& d : delta) d = 0.05 + 0.1 * u(rng);
      RenderSettings s;
      s.early_stop = 0;  // every sample contributes, so that every derivative is exercised
      s.background = 0.3f;
      const auto f = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
        const RayRender<double> r = renderRay(v.data(), v.data() + n, delta.data(),
                                              static_cast<const double*>(nullptr), n, channels, s);
        return Eigen::Map<const Eigen::VectorXd>(r.colour, channels);
      };
      const RayRender<double> fwd = renderRay(x.data(), x.data() + n, delta.data(),
                                              static_cast<const double*>(nullptr), n, channels, s);
      MatrixD J(channels, x.size());
      for (int c = 0; c < channels; ++c) {
        double dc[3] = {0, 0, 0};
        dc[c] = 1;
        std::vector<double> ds(n), dcol(n * static_cast<size_t>(channels));
        renderRayBackward(x.data(), x.data() + n, delta.data(), n, channels, s, fwd, dc, ds.data(),
                          dcol.data());
        for (size_t j = 0; j < n; ++j) J(c, static_cast<Eigen::Index>(j)) = ds[j];
        for (size_t j = 0; j < n * static_cast<size_t>(channels); ++j)
          J(c, static_cast<Eigen::Index>(n + j)) = dcol[j];
      }
      test::expectJacobianNear("render, scale " + std::to_string(scale), J, f, x, kEps, kTol);
    }
  }
}

TEST(VolumeRender, NoNanWithHugeDensitiesEmptyRaysOrBadInputs) {
  const double huge[4] = {1e30, 1e300, 0, 5}, colours[4] = {0.5, 0.2, 0.7, 0.1},
               delta[4] = {1, 1, 1, 1};
  RenderSettings s;
  const RayRender<double> r =
      renderRay(huge, colours, delta, static_cast<const double*>(nullptr), 4, 1, s);
  EXPECT_NEAR(r.colour[0], 0.5, 1e-12);  // the first sample is opaque
  EXPECT_EQ(r.used, 1u);                 // and stops the march
  double ds[4], dc[4];
  const double g = 1;
  renderRayBackward(huge, colours, delta, 4, 1, s, r, &g, ds, dc);
  for (double v : ds) EXPECT_TRUE(std::isfinite(v));
  const RayRender<double> empty =
      renderRay(huge, colours, delta, static_cast<const double*>(nullptr), 0, 1, s);
  EXPECT_EQ(empty.colour[0], 0.0);
  const double bad[3] = {NAN, -1, INFINITY}, badc[3] = {NAN, 0.5, 0.5}, d3[3] = {1, 1, 1};
  const RayRender<double> b =
      renderRay(bad, badc, d3, static_cast<const double*>(nullptr), 3, 1, s);
  EXPECT_TRUE(std::isfinite(b.colour[0]));
  double ds3[3], dc3[3];
  renderRayBackward(bad, badc, d3, 3, 1, s, b, &g, ds3, dc3);
  for (double v : ds3) EXPECT_TRUE(std::isfinite(v));
}

TEST(Mlp, BackwardAgainstCentralDifferencesWithSkip) {
  Mlp<double> mlp({4, 6, 5, 3}, 1, 7);
  MatrixD x = MatrixD::Random(4, 5);
  const MatrixD w = MatrixD::Random(3, 5);  // loss = <w, mlp(x)>
  Eigen::VectorXd params(static_cast<Eigen::Index>(mlp.parameterCount()));
  mlp.getParameters(params.data());
  mlp.zeroGradients();
  mlp.forward(x);
  const MatrixD dx = mlp.backward(w);
  Eigen::VectorXd grad(params.size());
  mlp.getGradients(grad.data());
  const auto loss_of_params = [&](const Eigen::VectorXd& p) -> Eigen::VectorXd {
    Mlp<double> m = mlp;
    m.setParameters(p.data());
    return Eigen::VectorXd::Constant(1, (w.array() * m.forward(x).array()).sum());
  };
  test::expectJacobianNear("mlp parameters", grad.transpose(), loss_of_params, params, kEps, kTol);
  const auto loss_of_input = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    Mlp<double> m = mlp;
    return Eigen::VectorXd::Constant(
        1, (w.array() * m.forward(Eigen::Map<const MatrixD>(v.data(), 4, 5)).array()).sum());
  };
  test::expectJacobianNear("mlp input", flat(dx).transpose(), loss_of_input, flat(x), kEps, kTol);
}

TEST(PositionalEncoding, BackwardAgainstCentralDifferences) {
  const MatrixD p = MatrixD::Random(3, 4);
  const MatrixD w = MatrixD::Random(3 * (1 + 2 * 6), 4);
  const MatrixD dp = positionalEncodingBackward(p, 6, w);
  const auto f = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    return Eigen::VectorXd::Constant(
        1, (w.array() *
            positionalEncoding(MatrixD(Eigen::Map<const MatrixD>(v.data(), 3, 4)), 6).array())
               .sum());
  };
  test::expectJacobianNear("positional encoding", flat(dp).transpose(), f, flat(p), kEps, kTol);
}

// Features 2 and 4 take the unrolled kernels, 3 the generic one.
class HashGridFeatures : public ::testing::TestWithParam<int> {};

TEST_P(HashGridFeatures, BackwardToTableAndPositionsAgainstCentralDifferences) {
  HashGridConfig c;
  c.levels = 3;
  c.features = GetParam();
  c.log2_table = 6;  // 64 entries: the finest level hashes
  c.base_resolution = 2;
  c.per_level_scale = 2.0;
  HashGrid<double> grid(c, 3);
  for (double& v : grid.table())
    v *= 1e4;  // O(1) features, so that position gradients are not tiny
  MatrixD x = (MatrixD::Random(3, 8).array() * 0.45 + 0.5).matrix();
  // Two samples outside the unit cube along some axes (clamped there: no gradient along those
  // axes, and the others' as inside).
  x.col(6) << 1.3, 0.4, 0.6;
  x.col(7) << 0.3, -0.2, 1.1;
  const MatrixD w = MatrixD::Random(grid.outputSize(), 8);
  grid.zeroGradients();
  grid.forward(x);
  const MatrixD dx = grid.backward(w);
  const auto of_positions = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    HashGrid<double> g = grid;
    return Eigen::VectorXd::Constant(
        1, (w.array() * g.forward(Eigen::Map<const MatrixD>(v.data(), 3, 8)).array()).sum());
  };
  test::expectJacobianNear("hash grid positions", flat(dx).transpose(), of_positions, flat(x), 1e-7,
                           1e-5);
  EXPECT_EQ(dx(0, 6), 0.0);
  EXPECT_NE(dx(1, 6), 0.0);
  EXPECT_EQ(dx(1, 7), 0.0);
  EXPECT_EQ(dx(2, 7), 0.0);
  EXPECT_NE(dx(0, 7), 0.0);
  const Eigen::VectorXd table = Eigen::Map<const Eigen::VectorXd>(
      grid.table().data(), static_cast<Eigen::Index>(grid.table().size()));
  const auto of_table = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    HashGrid<double> g = grid;
    std::copy(v.data(), v.data() + v.size(), g.table().begin());
    return Eigen::VectorXd::Constant(1, (w.array() * g.forward(x).array()).sum());
  };
  const Eigen::VectorXd grad = Eigen::Map<const Eigen::VectorXd>(
      grid.gradients().data(), static_cast<Eigen::Index>(grid.gradients().size()));
  test::expectJacobianNear("hash grid table", grad.transpose(), of_table, table, kEps, kTol);
  // Entries with gradient are exactly the touched ones.
  for (size_t e = 0; e < grid.touched().size(); ++e) {
    bool nonzero = false;
    for (int j = 0; j < c.features; ++j)
      nonzero |= grad(static_cast<Eigen::Index>(e) * c.features + j) != 0;
    if (nonzero) {
      EXPECT_TRUE(grid.touched()[e]) << e;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Kernels, HashGridFeatures, ::testing::Values(2, 3, 4));

TEST(HashGrid, RejectsAnUnsupportedConfiguration) {
  HashGridConfig c;
  c.features = 17;
  EXPECT_THROW(HashGrid<float>(c, 1), std::invalid_argument);
  c = HashGridConfig{};
  c.log2_table = 31;
  EXPECT_THROW(HashGrid<float>(c, 1), std::invalid_argument);
}

void checkField(RadianceField<double>& field, const std::string& name) {
  const int n = 4;
  MatrixD p = MatrixD::Random(3, n) * 0.8;
  const MatrixD w = MatrixD::Random(1 + field.channels(), n);
  field.zeroGradients();
  field.forward(p);
  const MatrixD dp = field.backward(w);
  const auto f = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    return Eigen::VectorXd::Constant(
        1, (w.array() * field.forward(Eigen::Map<const MatrixD>(v.data(), 3, n)).array()).sum());
  };
  test::expectJacobianNear(name + " positions", flat(dp).transpose(), f, flat(p), kEps, 1e-5);
  // Parameters: a spread of entries of every block.
  field.zeroGradients();
  field.forward(p);
  field.backward(w);
  for (ParameterBlock<double>& b : field.parameters()) {
    for (size_t i = 0; i < b.size; i += std::max<size_t>(1, b.size / 7)) {
      if (b.touched && !b.touched[i / b.row_size]) continue;
      const double keep = b.values[i];
      b.values[i] = keep + kEps;
      const double up = (w.array() * field.forward(p).array()).sum();
      b.values[i] = keep - kEps;
      const double down = (w.array() * field.forward(p).array()).sum();
      b.values[i] = keep;
      const double numeric = (up - down) / (2 * kEps);
      EXPECT_NEAR(b.gradients[i], numeric, 1e-5 * std::max(1.0, std::abs(numeric)))
          << name << " parameter " << i;
    }
  }
}

// Tiny fields for the gradient checks: an MLP with 3 frequencies and non-zero biases, a hash grid
// of 3 levels x 2 features with O(1) features instead of the 1e-4 initialisation (ReLU kinks stay
// far from the finite differences' steps). With the biases at their initial zero, a sample whose
// inputs to a layer all died had pre-activations of exactly 0 there, on the kink: the check then
// failed for about one draw of positions in 25.
std::unique_ptr<RadianceField<double>> tinyMlpField() {
  MlpFieldConfig mc;
  mc.frequencies = 3;
  mc.depth = 3;
  mc.width = 8;
  mc.skip = 2;
  mc.colour_width = 6;
  auto mlp = makeMlpField<double>(mc, 3, 1);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::vector<ParameterBlock<double>> blocks = mlp->parameters();  // weights, biases, per layer
  for (size_t b = 1; b < blocks.size(); b += 2) {
    for (size_t i = 0; i < blocks[b].size; ++i) blocks[b].values[i] = u(rng);
  }
  return mlp;
}
HashFieldConfig tinyHashConfig() {
  HashFieldConfig hc;
  hc.grid.levels = 3;
  hc.grid.features = 2;
  hc.grid.log2_table = 8;
  hc.grid.base_resolution = 4;
  hc.hidden = 8;
  return hc;
}
std::unique_ptr<RadianceField<double>> tinyHashField() {
  auto hash = makeHashField<double>(tinyHashConfig(), 1, 2);
  ParameterBlock<double> table = hash->parameters().front();
  for (size_t i = 0; i < table.size; ++i) table.values[i] *= 1e4;
  return hash;
}

TEST(Fields, BackwardOfBothFieldsAgainstCentralDifferences) {
  checkField(*tinyMlpField(), "mlp field");
  checkField(*tinyHashField(), "hash field");
}

// Coarse to fine: a partly open band limit is part of the function, so the gradients still match
// central differences; a closed band has no effect on the output and gets no gradient; a fully open
// one is the plain field.
TEST(Fields, BandLimitWeightsTheEncodingAndItsGradients) {
  auto mlp = tinyMlpField();
  EXPECT_EQ(mlp->bands(), 4);
  mlp->setBandLimit(1.5);
  checkField(*mlp, "band-limited mlp field");
  const HashFieldConfig hc = tinyHashConfig();
  auto hash = tinyHashField();
  EXPECT_EQ(hash->bands(), 3);
  ParameterBlock<double> table = hash->parameters().front();
  const MatrixD p = MatrixD::Random(3, 16) * 0.8;
  const MatrixD full = hash->forward(p);
  hash->setBandLimit(0.5);
  checkField(*hash, "band-limited hash field");
  const MatrixD half = hash->forward(p);
  EXPECT_GT((half - full).cwiseAbs().maxCoeff(), 1e-3) << "the band limit must change the output";
  // Closed: the finest level's entries neither change the output nor get gradients.
  hash->setBandLimit(0.0);
  const MatrixD coarse = hash->forward(p);
  const size_t finest = 2 * (size_t{1} << hc.grid.log2_table) * hc.grid.features;
  for (size_t i = finest; i < table.size; ++i) table.values[i] += 0.5;
  EXPECT_EQ((hash->forward(p) - coarse).cwiseAbs().maxCoeff(), 0.0);
  hash->zeroGradients();
  hash->forward(p);
  hash->backward(MatrixD::Ones(2, 16));
  double finest_gradient = 0;
  for (size_t i = finest; i < table.size; ++i)
    finest_gradient = std::max(finest_gradient, std::abs(table.gradients[i]));
  EXPECT_EQ(finest_gradient, 0.0);
  for (size_t i = finest; i < table.size; ++i) table.values[i] -= 0.5;
  hash->setBandLimit(hash->bands());
  EXPECT_LT((hash->forward(p) - full).cwiseAbs().maxCoeff(), 1e-12);
}

// The float hash field runs its MLP through register-blocked kernels (32 features into 64 hidden
// units) where the target has AVX-512 or AVX2 with FMA; Eigen's products (the path checked above
// against central differences, in double) are the reference: the same parameters and inputs must
// give the same outputs and gradients up to the order of float sums. 263 samples: a full block of
// 256 and a tail that is not a multiple of the kernels' tiles (4 samples with AVX-512, 2 with
// AVX2); fixed random inputs.
TEST(Fields, HashFieldKernelsMatchEigensProducts) {
  for (const int channels : {1, 3}) {
    HashFieldConfig c;  // 8 levels x 4 features, hidden 64
    c.grid.log2_table = 10;
    auto fast = makeHashField<float>(c, channels, 3);
    c.kernels = false;
    auto eigen = makeHashField<float>(c, channels, 3);
    std::vector<ParameterBlock<float>> pf = fast->parameters(), pe = eigen->parameters();
    ASSERT_EQ(pf.size(), pe.size());
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    for (size_t b = 0; b < pf.size(); ++b) {
      for (size_t i = 0; i < pf[b].size; ++i) {
        // O(1) features (as above) and non-zero biases.
        pf[b].values[i] = pe[b].values[i] =
            b == 0 ? pf[b].values[i] * 1e4f : pf[b].values[i] + 0.1f * u(rng);
      }
    }
    const int n = 263;
    Eigen::MatrixXf p(3, n), w(1 + channels, n);
    for (float& v : p.reshaped()) v = 0.9f * u(rng);
    for (float& v : w.reshaped()) v = u(rng);
    fast->zeroGradients();
    eigen->zeroGradients();
    const Eigen::MatrixXf out_f = fast->forward(p), out_e = eigen->forward(p);
    const Eigen::MatrixXf dp_f = fast->backward(w), dp_e = eigen->backward(w);
    EXPECT_LT((out_f - out_e).cwiseAbs().maxCoeff(),
              1e-5f * std::max(1.0f, out_e.cwiseAbs().maxCoeff()))
        << channels;
    EXPECT_LT((dp_f - dp_e).cwiseAbs().maxCoeff(),
              1e-4f * std::max(1.0f, dp_e.cwiseAbs().maxCoeff()))
        << channels;
    for (size_t b = 0; b < pf.size(); ++b) {
      float scale = 1, worst = 0;
      for (size_t i = 0; i < pf[b].size; ++i) scale = std::max(scale, std::abs(pe[b].gradients[i]));
      for (size_t i = 0; i < pf[b].size; ++i)
        worst = std::max(worst, std::abs(pf[b].gradients[i] - pe[b].gradients[i]));
      EXPECT_LT(worst, 1e-4f * scale) << "block " << b << ", channels " << channels;
    }
  }
}

// The hash field's forward and backward and Adam's step deal their work to whichever thread is
// free (blocks of samples, lanes of parameter sums, the grid's levels, runs of table rows), each
// piece summed on its own and the pieces added in a fixed order: one thread and two must give
// the same bits. 5,000 samples: 20 blocks and a tail, 16 lanes, every level.
TEST(Fields, HashFieldAndAdamGiveTheSameBitsOnOneThreadAndTwo) {
  HashFieldConfig c;
  c.grid.log2_table = 12;
  const int n = 5000;
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  Eigen::MatrixXf p(3, n), w(4, n);
  for (float& v : p.reshaped()) v = 0.95f * u(rng);
  for (float& v : w.reshaped()) v = u(rng);
  struct Run {
    Eigen::MatrixXf out, dp;
    std::vector<std::vector<float>> gradients, values;
  };
  const auto run = [&](int threads) {
    const int saved = omp_get_max_threads();
    omp_set_num_threads(threads);
    auto field = makeHashField<float>(c, 3, 4);
    Adam<float> adam(field->parameters(), AdamOptions{});
    Run r;
    for (int step = 0; step < 2; ++step) {
      field->zeroGradients();
      r.out = field->forward(p);
      r.dp = field->backward(w);
      adam.step();
    }
    for (const ParameterBlock<float>& b : field->parameters()) {
      r.gradients.emplace_back(b.gradients, b.gradients + b.size);
      r.values.emplace_back(b.values, b.values + b.size);
    }
    omp_set_num_threads(saved);
    return r;
  };
  const Run one = run(1), two = run(2);
  EXPECT_TRUE(one.out == two.out);
  EXPECT_TRUE(one.dp == two.dp);
  ASSERT_EQ(one.gradients.size(), two.gradients.size());
  for (size_t b = 0; b < one.gradients.size(); ++b) {
    EXPECT_TRUE(one.gradients[b] == two.gradients[b]) << "block " << b;
    EXPECT_TRUE(one.values[b] == two.values[b]) << "block " << b;
  }
  // The step moved the table (the comparison is not of two untouched copies).
  auto untrained = makeHashField<float>(c, 3, 4);
  const ParameterBlock<float> table = untrained->parameters()[0];
  EXPECT_FALSE(one.values[0] == std::vector<float>(table.values, table.values + table.size));
}

TEST(Camera, NdcPointPoseJacobianAgainstCentralDifferences) {
  PinholeCamera cam = PinholeCamera{60.0, 58.0, 31.5, 23.5, {}}.withSize(64, 48);
  const SE3 T(expSO3(Vector3(0.02, -0.03, 0.01)), Vector3(0.05, -0.02, 0.03));
  for (const std::vector<double>& dist :
       {std::vector<double>{}, std::vector<double>{-0.2, 0.05, 0.001, -0.002}}) {
    cam.distortion = dist;
    for (double t : {0.0, 0.3, 0.9}) {
      for (const auto& [u, v] :
           std::vector<std::pair<double, double>>{{3, 4}, {31.5, 23.5}, {60, 40}}) {
        const auto f = [&](const Eigen::VectorXd& eps) -> Eigen::VectorXd {
          const NdcRay r = toNdc(worldRay(cam, T * expSE3(Vector6(eps)), u, v), cam, 1.0);
          return r.origin + t * r.direction;
        };
        test::expectJacobianNear("ndc point, t " + std::to_string(t),
                                 ndcPointPoseJacobian(cam, T, u, v, t, 1.0), f, Vector6::Zero(),
                                 kEps, 1e-6);
      }
    }
    // Distortion round trip: a pixel's direction projects back onto the pixel.
    const Eigen::Vector2d back = projectPoint(cam, pixelDirection(cam, 10.0, 40.0));
    EXPECT_NEAR(back.x(), 10.0, 1e-9);
    EXPECT_NEAR(back.y(), 40.0, 1e-9);
  }
}

// The projection's derivative by the camera-frame point, with and without a lens's distortion
// (radial to k3 and tangential), near the centre and out towards a corner.
TEST(Camera, ProjectionJacobianAgainstCentralDifferences) {
  PinholeCamera cam = PinholeCamera{60.0, 58.0, 31.5, 23.5, {}}.withSize(64, 48);
  for (const std::vector<double>& dist :
       {std::vector<double>{}, std::vector<double>{-0.3, 0.08, 0.002, -0.003, 0.01}}) {
    cam.distortion = dist;
    for (const Vector3& point : {Vector3(0.01, -0.02, 1.0), Vector3(0.5, 0.35, 1.3),
                                 Vector3(-0.9, 0.6, 2.0), Vector3(0.2, -0.7, 0.8)}) {
      Eigen::Matrix<double, 2, 3> jacobian;
      const Eigen::Vector2d q = projectPoint(cam, point, jacobian);
      const Eigen::Vector2d plain = projectPoint(cam, point);
      EXPECT_EQ(q, plain);
      const auto f = [&](const Eigen::VectorXd& p) -> Eigen::VectorXd {
        return projectPoint(cam, Vector3(p));
      };
      test::expectJacobianNear("projection, k1 " + std::to_string(dist.empty() ? 0 : dist[0]),
                               jacobian, f, Eigen::VectorXd(point), kEps, 1e-6);
    }
  }
}

TEST(RayBatch, PoseGradientsAgainstCentralDifferences) {
  // A loss L = sum_r w_r . colour_r over rays from two poses, with depth scaled as BeNeRF's field
  // sees it: dL/d pose (right perturbation) from backward() against central differences.
  const PinholeCamera cam = PinholeCamera{14.0, 13.0, 7.5, 5.5, {}}.withSize(16, 12);
  const auto field = tinyMlpField();
  const std::vector<SE3> poses = {
      expSE3((Vector6() << 0.01, -0.02, 0.005, 0.03, -0.01, 0.02).finished()),
      expSE3((Vector6() << -0.02, 0.01, 0.01, -0.02, 0.04, -0.01).finished())};
  const RayBatchOptions options{.samples = 6, .near = 1.0, .depth_scale = 0.3, .render = {}};
  std::vector<RayBatch<double>::PixelRay> rays;
  for (int r = 0; r < 10; ++r)
    rays.push_back({(3 * r + 1) % cam.width, (5 * r + 2) % cam.height, r % 2});
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float> jitter(rays.size() * 6);
  for (float& j : jitter) j = u(rng);
  std::vector<double> weights(rays.size() * 3);
  for (double& w : weights) w = u(rng) - 0.5;
  const auto loss = [&](const std::vector<SE3>& at) {
    RayBatch<double> batch(cam, options);
    batch.setRays(at, rays, jitter.data());
    batch.forward(*field, false);
    double l = 0;
    for (int r = 0; r < batch.size(); ++r) {
      for (int c = 0; c < 3; ++c)
        l += weights[static_cast<size_t>(r) * 3 + c] * batch.render(r).colour[c];
    }
    return l;
  };
  RayBatch<double> batch(cam, options);
  batch.setRays(poses, rays, jitter.data());
  field->zeroGradients();
  batch.forward(*field, true);
  const std::vector<Vector6> analytic = batch.backward(*field, weights, true);
  ASSERT_EQ(analytic.size(), 2u);
  for (size_t k = 0; k < poses.size(); ++k) {
    Eigen::MatrixXd a = analytic[k].transpose();
    test::expectJacobianNear(
        "pose " + std::to_string(k), a,
        [&](const Eigen::VectorXd& eps) {
          std::vector<SE3> at = poses;
          at[k] = poses[k] * expSE3(Vector6(eps));
          return Eigen::VectorXd::Constant(1, loss(at));
        },
        Eigen::VectorXd::Zero(6), 1e-6, 1e-5);
    EXPECT_GT(analytic[k].norm(), 1e-4) << "the check must see a gradient";
  }
}

TEST(Sampling, ImportanceSamplesFollowTheWeights) {
  std::vector<float> t, w;
  for (int j = 0; j < 16; ++j) {
    t.push_back(j / 16.0f);
    w.push_back(j == 9 ? 1.0f : 0.0f);  // all the mass in [9/16, 10/16)
  }
  std::vector<float> u;
  for (int k = 0; k < 64; ++k) u.push_back((k + 0.5f) / 64);
  const std::vector<float> s = importanceSamples(t, w, u);
  ASSERT_EQ(s.size(), 64u);
  EXPECT_TRUE(std::is_sorted(s.begin(), s.end()));
  const long inside =
      std::count_if(s.begin(), s.end(), [](float v) { return v >= 9 / 16.0f && v < 10 / 16.0f; });
  EXPECT_GE(inside, 60);  // the floor leaves a few elsewhere
  // Uniform weights give evenly spread samples; NaN weights count as zero.
  std::vector<float> uniform(16, 1.0f);
  uniform[3] = NAN;
  const std::vector<float> e = importanceSamples(t, uniform, u);
  for (float v : e) EXPECT_TRUE(v >= 0 && v < 1);
  EXPECT_NEAR(e[32], 0.5f, 0.07f);
}

TEST(Grey, WeightsAndBackward) {
  const double bgr[3] = {0.2, 0.4, 0.6};
  EXPECT_NEAR(greyOf(bgr, 3), 0.114 * 0.2 + 0.587 * 0.4 + 0.299 * 0.6, 1e-15);
  double d[3];
  greyBackward(2.0, 3, d);
  EXPECT_DOUBLE_EQ(d[2], 0.598);
}

TEST(Adam, SparseBlocksUpdateOnlyTouchedRowsAndTheRateDecays) {
  std::vector<double> values = {1, 1, 1, 1}, grads = {0.5, 0.5, 0.5, 0.5};
  std::vector<uint8_t> touched = {1, 0};
  AdamOptions o;
  o.learning_rate = 0.1;
  o.decay_rate = 0.5;
  o.decay_steps = 10;
  Adam<double> adam({ParameterBlock<double>{values.data(), grads.data(), 4, touched.data(), 2}}, o);
  adam.step();
  EXPECT_NEAR(values[0], 0.9, 1e-9);  // the first Adam step moves by lr
  EXPECT_NEAR(values[1], 0.9, 1e-9);
  EXPECT_EQ(values[2], 1.0);
  EXPECT_EQ(values[3], 1.0);
  for (int i = 0; i < 9; ++i) adam.step();
  EXPECT_NEAR(adam.learningRate(), 0.05, 1e-12);
}

// A tiny scene (two textured planes) seen from 4 poses: the hash field fits it.
TEST(Training, HashFieldFitsATinySceneAndIsDeterministicWithOneThread) {
  const synth::Scene scene = synth::makePreset("text", {});
  const int w = 40, h = 30;
  const Calibration k = synth::defaultCamera(w, h);
  const PinholeCamera cam = k.withSize(w, h);
  std::vector<TrainingView> views;
  for (int i = 0; i < 4; ++i) {
    const SE3 pose(expSO3(Vector3(0.01 * i, -0.008 * i, 0)), Vector3(0.02 * i, 0.01 * (i % 2), 0));
    views.push_back({synth::render(scene, k, w, h, pose), pose});
  }
  HashFieldConfig hc;
  hc.grid.levels = 8;
  hc.grid.log2_table = 14;
  FitOptions fo;
  fo.steps = 250;
  fo.rays_per_step = 256;
  fo.samples_per_ray = 32;
  fo.adam.learning_rate = 1e-2;
  auto field = makeHashField<float>(hc, 1, 5);
  const FitReport report = fitField(*field, cam, views, fo);
  EXPECT_LT(report.loss.back().second, report.loss.front().second / 10);
  const cv::Mat rendered = renderImage(*field, cam, views[1].pose, 32, fo.near);
  const double mse = cv::norm(rendered - views[1].image, cv::NORM_L2SQR) / (w * h);
  const double psnr = -10 * std::log10(mse);
  EXPECT_GT(psnr, 22.0) << "loss " << report.loss.back().second;
  EXPECT_TRUE(cv::checkRange(rendered));
  // With importance samples on top of the coarse ones the fitted scene still renders well.
  const cv::Mat refined = renderImage(*field, cam, views[1].pose, 32, fo.near, {}, 32);
  const double psnr_refined =
      -10 * std::log10(cv::norm(refined - views[1].image, cv::NORM_L2SQR) / (w * h));
  EXPECT_GT(psnr_refined, 22.0);
  FitOptions hierarchical = fo;
  hierarchical.steps = 60;
  hierarchical.samples_per_ray = 16;
  hierarchical.importance_samples = 16;
  auto h_field = makeHashField<float>(hc, 1, 6);
  const FitReport hr = fitField(*h_field, cam, views, hierarchical);
  EXPECT_LT(hr.loss.back().second, hr.loss.front().second / 3);
  // Deterministic for a seed with one thread.
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  FitOptions shortfit = fo;
  shortfit.steps = 5;
  auto a = makeHashField<float>(hc, 1, 5), b = makeHashField<float>(hc, 1, 5);
  const FitReport ra = fitField(*a, cam, views, shortfit), rb = fitField(*b, cam, views, shortfit);
  omp_set_num_threads(threads);
  for (size_t i = 0; i < ra.loss.size(); ++i) EXPECT_EQ(ra.loss[i].second, rb.loss[i].second);
}

}  // namespace
}  // namespace evkit::nerf
