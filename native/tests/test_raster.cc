// Plain C++ tests of kernels/raster (no framework): one triangle's coverage, the
// pixels visited against every pixel of the image, a finite-difference check of
// the backward in double (a face drawn row by row and one drawn as one chunk),
// and input validation.
// Exit status is the number of failed checks (at most 255).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "kernels/raster.h"
#include "kernels/raster_pairs.h"

using namespace jaxgenus;

#include "check.h"

namespace {

constexpr int64_t kH = 16, kW = 20;

struct Scene {
  std::vector<double> v = {3.2, 2.7, 15.1, 4.3, 7.6, 13.4};  // one triangle, pixel coordinates
  std::vector<double> plane = {0.01, 0.02, 0.3};
  std::vector<double> qrange = {0.3, 0.75};
  std::vector<double> attr = {0.4, -0.7};
  std::vector<double> logw = {-0.2};
  std::vector<double> dconst = {2.0, 0.5};
  bool valid[1] = {true};
  double sigma = 0.8;
  bool planes = false;  // attr holds (gx, gy, c, lo, hi) per channel
  std::vector<double> background = {0.1, 0.2, 0.3};

  RasterConfig config() const {
    RasterConfig c;
    c.height = kH;
    c.width = kW;
    c.sigma = sigma;
    c.gamma = 0.05;
    c.sharpness = 1.2;
    c.n_attr = 2;
    c.attr_planes = planes;
    c.want_depth = true;
    c.background = background.data();
    return c;
  }
  RasterFaces<double> faces() const {
    RasterFaces<double> f;
    f.n_views = 1;
    f.n_faces = 1;
    f.v = v.data();
    f.plane = plane.data();
    f.qrange = qrange.data();
    f.attr = attr.data();
    f.logw = logw.data();
    f.valid = valid;
    f.dconst = dconst.data();
    return f;
  }
};

struct Out {
  std::vector<double> cov = std::vector<double>(kH * kW), blend = std::vector<double>(kH * kW * 3),
                      mlw = std::vector<double>(kH * kW);
};

Out forward(const Scene& s) {
  Out o;
  std::string err;
  const Status st = raster_forward(s.config(), s.faces(), o.cov.data(), o.blend.data(), o.mlw.data(), &err);
  CHECK(st == Status::kOk, "forward failed: %s", err.c_str());
  return o;
}

double loss(const Scene& s, const std::vector<double>& wc, const std::vector<double>& wb) {
  const Out o = forward(s);
  double l = 0;
  for (size_t i = 0; i < o.cov.size(); ++i) l += wc[i] * o.cov[i];
  for (size_t i = 0; i < o.blend.size(); ++i) l += wb[i] * o.blend[i];
  return l;
}

void test_coverage() {
  Scene s;
  s.logw[0] = 0.0;
  s.sigma = 0.2;  // blur radius 1.84 px
  const Out o = forward(s);
  // centroid (8.63, 6.8) lies in pixel (8, 6) whose centre is well inside
  CHECK(std::abs(o.cov[6 * kW + 8] - 1.0) < 1e-6, "cov at centroid %g", o.cov[6 * kW + 8]);
  CHECK(o.cov[15 * kW + 19] == 0.0, "far pixel cov %g", o.cov[15 * kW + 19]);
  CHECK(o.cov[0] == 0.0, "corner cov %g", o.cov[0]);
  // far away: the blend is the background, exactly
  for (int c = 0; c < 3; ++c)
    CHECK(std::abs(o.blend[(15 * kW + 19) * 3 + c] - s.background[c]) < 1e-15, "background channel %d", c);
  // the centroid's blend is (close to) the face attributes
  CHECK(std::abs(o.blend[(6 * kW + 8) * 3] - 0.4) < 1e-3, "blend %g", o.blend[(6 * kW + 8) * 3]);
}

// A face whose blurred box has at most 32 pixels: drawn as one chunk of its box
// (the default scene's face goes row by row).
Scene small_face() {
  Scene s;
  s.v = {8.3, 6.2, 10.1, 6.9, 8.9, 7.8};
  s.sigma = 0.12;  // blur radius 1.1 px: box 5 x 4 pixels
  return s;
}

void test_small_face_is_one_chunk() {
  const Scene s = small_face();
  const Out o = forward(s);
  int drawn = 0;
  for (double c : o.cov) drawn += c > 0;
  CHECK(drawn > 0 && drawn <= 32, "small face drew %d pixels", drawn);
  const double peak = *std::max_element(o.cov.begin(), o.cov.end());
  CHECK(peak > 0.5 && peak <= 1.0, "small face peak coverage %g", peak);
}

// Coverage from evaluating the pair at every pixel of the image, one pixel at a
// time: the footprint the kernel visits must not miss a contributing pixel.
void test_footprint_misses_nothing(const Scene& s) {
  using namespace raster_detail;
  const RasterConfig cfg = s.config();
  const RasterFaces<double> fs = s.faces();
  const Consts<double> k(cfg);
  Face<double> f{};
  const bool made = make_face(fs, 0, 0, cfg.n_attr, f);
  CHECK(made, "face not made");
  if (!made) return;
  Chunk<double> ch;
  Pair<double> p;
  const Out o = forward(s);
  for (int64_t row = 0; row < kH; ++row)
    for (int64_t col = 0; col < kW; ++col) {
      ch.px[0] = col + 0.5;
      ch.py[0] = row + 0.5;
      chunk_geometry(f, 1, ch);
      const double want = eval_pair(f, k, ch, 0, false, false, p) ? p.tv * f.w : 0.0;
      const double got = o.cov[row * kW + col];
      CHECK(std::abs(got - want) <= 1e-15, "pixel (%lld, %lld): cov %.17g, every-pixel %.17g", (long long)row,
            (long long)col, got, want);
    }
}

void test_finite_differences(const Scene& s) {
  std::mt19937 rng(7);
  std::normal_distribution<double> nd;
  std::vector<double> wc(kH * kW), wb(kH * kW * 3);
  for (auto& x : wc) x = nd(rng);
  for (auto& x : wb) x = nd(rng);
  const Out o = forward(s);
  std::vector<double> gv(6), gplane(3), gq(2), gattr(s.attr.size()), glogw(1), gdc(2);
  RasterCotangents<double> cot{o.blend.data(), o.mlw.data(), wc.data(), wb.data()};
  RasterGrads<double> g{gv.data(), gplane.data(), gq.data(), gattr.data(), glogw.data(), gdc.data()};
  std::string err;
  CHECK(raster_backward(s.config(), s.faces(), cot, g, &err) == Status::kOk, "backward: %s", err.c_str());
  struct Field {
    const char* name;
    std::vector<double> Scene::*member;
    std::vector<double>* grad;
  };
  const Field fields[] = {{"v", &Scene::v, &gv},         {"plane", &Scene::plane, &gplane},
                          {"qrange", &Scene::qrange, &gq}, {"attr", &Scene::attr, &gattr},
                          {"logw", &Scene::logw, &glogw}, {"dconst", &Scene::dconst, &gdc}};
  const double h = 1e-6;
  for (const Field& f : fields) {
    for (size_t i = 0; i < (s.*f.member).size(); ++i) {
      Scene a = s, b = s;
      (a.*f.member)[i] += h;
      (b.*f.member)[i] -= h;
      const double fd = (loss(a, wc, wb) - loss(b, wc, wb)) / (2 * h);
      const double an = (*f.grad)[i];
      CHECK(std::abs(fd - an) <= 1e-5 * (1.0 + std::abs(fd)), "%s[%zu]: fd %.9g analytic %.9g", f.name, i, fd,
            an);
    }
  }
}

// The same triangle with its attributes as clamped planes in the pixel (an interpolated colour):
// channel 0 reaches its lower clamp over part of the face, channel 1 its upper one.
Scene planes_scene() {
  Scene s;
  s.planes = true;
  s.attr = {0.05, -0.03, 0.2, 0.1037, 0.8913, -0.02, 0.04, -0.5, -0.9, -0.3};  // no pixel sits on a clamp's kink
  return s;
}

void test_planes_are_evaluated_per_pixel() {
  const Scene s = planes_scene();
  const Out o = forward(s);
  // deep inside the face the blend is the face's value (the background's weight is tiny there)
  const int64_t row = 7, col = 9;
  const double u = col + 0.5, v = row + 0.5;
  const double* b = o.blend.data() + (row * kW + col) * 3;
  const double want0 = std::clamp(0.05 * u - 0.03 * v + 0.2, 0.1037, 0.8913);
  const double want1 = std::clamp(-0.02 * u + 0.04 * v - 0.5, -0.9, -0.3);
  CHECK(std::abs(b[0] - want0) < 1e-3 && std::abs(b[1] - want1) < 1e-3, "plane values %.6g %.6g, want %.6g %.6g",
        b[0], b[1], want0, want1);
}

void test_validation() {
  Scene s;
  Out o;
  std::string err;
  RasterConfig c = s.config();
  c.height = 0;
  CHECK(raster_forward(c, s.faces(), o.cov.data(), o.blend.data(), o.mlw.data(), &err) == Status::kInvalidInput,
        "height 0 accepted");
  CHECK(!err.empty(), "no message");
  c = s.config();
  c.sigma = -1.0;
  CHECK(raster_forward(c, s.faces(), o.cov.data(), o.blend.data(), o.mlw.data(), &err) == Status::kInvalidInput,
        "negative sigma accepted");
  RasterFaces<double> f = s.faces();
  f.plane = nullptr;
  CHECK(raster_forward(s.config(), f, o.cov.data(), o.blend.data(), o.mlw.data(), &err) == Status::kInvalidInput,
        "null plane accepted");
  CHECK(raster_forward(s.config(), s.faces(), o.cov.data(), static_cast<double*>(nullptr), o.mlw.data(), &err) == Status::kInvalidInput,
        "null blend accepted");
  // a non-finite vertex is skipped, not a crash
  Scene bad = s;
  bad.v[0] = std::nan("");
  const Out ob = forward(bad);
  CHECK(*std::max_element(ob.cov.begin(), ob.cov.end()) == 0.0, "NaN face drawn");
}

}  // namespace

int main() {
  test_coverage();
  test_finite_differences(Scene());
  test_small_face_is_one_chunk();
  test_footprint_misses_nothing(Scene());
  test_footprint_misses_nothing(small_face());
  test_finite_differences(small_face());
  test_planes_are_evaluated_per_pixel();
  test_finite_differences(planes_scene());
  test_validation();
  if (g_failures == 0) std::printf("test_raster: all passed\n");
  return std::min(g_failures, 255);
}
