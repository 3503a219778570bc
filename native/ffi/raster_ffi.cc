// Thin XLA FFI adapter for kernels/raster: the splat forward and its VJP.
//
// Every buffer may carry extra leading (batch) dimensions, shared by all of them
// (vmap's broadcast_all): the kernel treats their product as the view axis.
// Float buffers are all float32 or all float64 (the kernel is templated on it).
#include <string>
#include <vector>

#include "ffi/handlers.h"
#include "kernels/raster.h"

namespace ffi = xla::ffi;

namespace {

struct Attrs {
  int64_t height, width, want_cov, n_attr, attr_planes, want_depth;
  double sigma, gamma, sharpness;
  ffi::Span<const double> background;
};

// Checks `d` == lead + tail (lead taken from the first buffer checked when empty).
class ShapeCheck {
 public:
  explicit ShapeCheck(const char* op) : op_(op) {}
  bool operator()(const char* name, ffi::AnyBuffer::Dimensions d, std::vector<int64_t> tail,
                  ffi::DataType dtype, ffi::DataType want) {
    if (!error_.empty()) return false;
    std::string expect = "(...";
    for (int64_t t : tail) expect += ", " + std::to_string(t);
    expect += ")";
    if (d.size() < tail.size()) return Fail(name, "must have shape " + expect);
    const size_t nl = d.size() - tail.size();
    if (!have_lead_) {
      lead_.assign(d.begin(), d.begin() + nl);
      have_lead_ = true;
    }
    if (nl != lead_.size()) return Fail(name, "has batch dimensions that differ from v's");
    for (size_t i = 0; i < nl; ++i)
      if (d[i] != lead_[i]) return Fail(name, "has batch dimensions that differ from v's");
    for (size_t i = 0; i < tail.size(); ++i)
      if (tail[i] >= 0 && d[nl + i] != tail[i]) return Fail(name, "must have shape " + expect);
    if (dtype != want) return Fail(name, "has the wrong dtype (all float inputs share v's dtype)");
    return true;
  }
  int64_t views() const {
    int64_t n = 1;
    for (int64_t x : lead_) n *= x;
    return n;
  }
  ffi::Error error() const {
    return error_.empty() ? ffi::Error::Success() : ffi::Error::InvalidArgument(error_);
  }

 private:
  bool Fail(const char* name, const std::string& what) {
    error_ = std::string(op_) + ": " + name + " " + what;
    return false;
  }
  const char* op_;
  std::string error_;
  std::vector<int64_t> lead_;
  bool have_lead_ = false;
};

ffi::Error CheckAttrs(const char* op, const Attrs& a, jaxgenus::RasterConfig* cfg) {
  const int64_t nb = a.n_attr + (a.want_depth ? 1 : 0);
  if (a.height <= 0 || a.width <= 0 || a.n_attr < 0)
    return ffi::Error::InvalidArgument(std::string(op) + ": height, width must be > 0 and n_attr >= 0");
  if (static_cast<int64_t>(a.background.size()) < nb)
    return ffi::Error::InvalidArgument(std::string(op) + ": background needs n_attr + want_depth values");
  cfg->height = a.height;
  cfg->width = a.width;
  cfg->sigma = a.sigma;
  cfg->gamma = a.gamma;
  cfg->sharpness = a.sharpness;
  cfg->want_cov = a.want_cov != 0;
  cfg->n_attr = a.n_attr;
  cfg->attr_planes = a.attr_planes != 0;
  cfg->want_depth = a.want_depth != 0;
  cfg->background = a.background.begin();
  return ffi::Error::Success();
}

// Checks the face inputs; returns the face count through *nf.
ffi::Error CheckFaces(ShapeCheck& chk, const jaxgenus::RasterConfig& cfg, ffi::AnyBuffer v, ffi::AnyBuffer plane,
                      ffi::AnyBuffer qrange, ffi::AnyBuffer attr, ffi::AnyBuffer logw,
                      ffi::Buffer<ffi::PRED> valid, ffi::AnyBuffer dconst, int64_t* nf) {
  const ffi::DataType dt = v.element_type();
  if (dt != ffi::DataType::F32 && dt != ffi::DataType::F64)
    return ffi::Error::InvalidArgument("raster: v must be float32 or float64");
  if (v.dimensions().size() < 3) return ffi::Error::InvalidArgument("raster: v must have shape (..., F, 3, 2)");
  *nf = v.dimensions()[v.dimensions().size() - 3];
  const int64_t F = *nf;
  chk("v", v.dimensions(), {F, 3, 2}, dt, dt) && chk("plane", plane.dimensions(), {F, 3}, plane.element_type(), dt) &&
      chk("qrange", qrange.dimensions(), {F, 2}, qrange.element_type(), dt) &&
      chk("attr", attr.dimensions(), {F, cfg.n_attr * cfg.attr_stride()}, attr.element_type(), dt) &&
      chk("logw", logw.dimensions(), {F}, logw.element_type(), dt) &&
      chk("valid", valid.dimensions(), {F}, ffi::DataType::PRED, ffi::DataType::PRED) &&
      chk("dconst", dconst.dimensions(), {2}, dconst.element_type(), dt);
  return chk.error();
}

template <typename T>
jaxgenus::RasterFaces<T> Faces(int64_t views, int64_t nf, ffi::AnyBuffer v, ffi::AnyBuffer plane,
                               ffi::AnyBuffer qrange, ffi::AnyBuffer attr, ffi::AnyBuffer logw,
                               ffi::Buffer<ffi::PRED> valid, ffi::AnyBuffer dconst) {
  jaxgenus::RasterFaces<T> f;
  f.n_views = views;
  f.n_faces = nf;
  f.v = static_cast<const T*>(v.untyped_data());
  f.plane = static_cast<const T*>(plane.untyped_data());
  f.qrange = static_cast<const T*>(qrange.untyped_data());
  f.attr = static_cast<const T*>(attr.untyped_data());
  f.logw = static_cast<const T*>(logw.untyped_data());
  f.valid = reinterpret_cast<const bool*>(valid.typed_data());
  f.dconst = static_cast<const T*>(dconst.untyped_data());
  return f;
}

template <typename T>
T* Out(ffi::Result<ffi::AnyBuffer>& r) {
  return static_cast<T*>(r->untyped_data());
}

ffi::Error Finish(jaxgenus::Status s, const std::string& msg) {
  if (s == jaxgenus::Status::kOk) return ffi::Error::Success();
  return ffi::Error::InvalidArgument(msg.empty() ? "raster: invalid input" : msg);
}

ffi::Error ForwardImpl(ffi::AnyBuffer v, ffi::AnyBuffer plane, ffi::AnyBuffer qrange, ffi::AnyBuffer attr,
                       ffi::AnyBuffer logw, ffi::Buffer<ffi::PRED> valid, ffi::AnyBuffer dconst, int64_t height,
                       int64_t width, double sigma, double gamma, double sharpness, int64_t want_cov,
                       int64_t n_attr, int64_t attr_planes, int64_t want_depth, ffi::Span<const double> background,
                       ffi::Result<ffi::AnyBuffer> cov, ffi::Result<ffi::AnyBuffer> blend,
                       ffi::Result<ffi::AnyBuffer> mlw) {
  jaxgenus::RasterConfig cfg;
  const Attrs a{height, width, want_cov, n_attr, attr_planes, want_depth, sigma, gamma, sharpness, background};
  if (ffi::Error e = CheckAttrs("raster_forward", a, &cfg); e.failure()) return e;
  ShapeCheck chk("raster_forward");
  int64_t nf = 0;
  if (ffi::Error e = CheckFaces(chk, cfg, v, plane, qrange, attr, logw, valid, dconst, &nf); e.failure()) return e;
  const ffi::DataType dt = v.element_type();
  const int64_t H = height, W = width, C = cfg.n_blend();
  chk("cov", cov->dimensions(), {H, W}, cov->element_type(), dt) &&
      chk("blend", blend->dimensions(), {H, W, C}, blend->element_type(), dt) &&
      chk("mlw", mlw->dimensions(), {H, W}, mlw->element_type(), dt);
  if (ffi::Error e = chk.error(); e.failure()) return e;
  std::string msg;
  jaxgenus::Status s;
  if (dt == ffi::DataType::F32) {
    s = jaxgenus::raster_forward(cfg, Faces<float>(chk.views(), nf, v, plane, qrange, attr, logw, valid, dconst),
                                 Out<float>(cov), Out<float>(blend), Out<float>(mlw), &msg);
  } else {
    s = jaxgenus::raster_forward(cfg, Faces<double>(chk.views(), nf, v, plane, qrange, attr, logw, valid, dconst),
                                 Out<double>(cov), Out<double>(blend), Out<double>(mlw), &msg);
  }
  return Finish(s, msg);
}

template <typename T>
jaxgenus::Status Backward(const jaxgenus::RasterConfig& cfg, const jaxgenus::RasterFaces<T>& faces,
                          ffi::AnyBuffer blend, ffi::AnyBuffer mlw, ffi::AnyBuffer g_cov, ffi::AnyBuffer g_blend,
                          ffi::Result<ffi::AnyBuffer>& gv, ffi::Result<ffi::AnyBuffer>& gplane,
                          ffi::Result<ffi::AnyBuffer>& gqrange, ffi::Result<ffi::AnyBuffer>& gattr,
                          ffi::Result<ffi::AnyBuffer>& glogw, ffi::Result<ffi::AnyBuffer>& gdconst,
                          std::string* msg) {
  jaxgenus::RasterCotangents<T> cot;
  cot.blend = static_cast<const T*>(blend.untyped_data());
  cot.mlw = static_cast<const T*>(mlw.untyped_data());
  cot.g_cov = static_cast<const T*>(g_cov.untyped_data());
  cot.g_blend = static_cast<const T*>(g_blend.untyped_data());
  jaxgenus::RasterGrads<T> g;
  g.v = Out<T>(gv);
  g.plane = Out<T>(gplane);
  g.qrange = Out<T>(gqrange);
  g.attr = Out<T>(gattr);
  g.logw = Out<T>(glogw);
  g.dconst = Out<T>(gdconst);
  return jaxgenus::raster_backward(cfg, faces, cot, g, msg);
}

ffi::Error BackwardImpl(ffi::AnyBuffer v, ffi::AnyBuffer plane, ffi::AnyBuffer qrange, ffi::AnyBuffer attr,
                        ffi::AnyBuffer logw, ffi::Buffer<ffi::PRED> valid, ffi::AnyBuffer dconst,
                        ffi::AnyBuffer blend, ffi::AnyBuffer mlw, ffi::AnyBuffer g_cov, ffi::AnyBuffer g_blend,
                        int64_t height, int64_t width, double sigma, double gamma, double sharpness,
                        int64_t want_cov, int64_t n_attr, int64_t attr_planes, int64_t want_depth, ffi::Span<const double> background,
                        ffi::Result<ffi::AnyBuffer> gv, ffi::Result<ffi::AnyBuffer> gplane,
                        ffi::Result<ffi::AnyBuffer> gqrange, ffi::Result<ffi::AnyBuffer> gattr,
                        ffi::Result<ffi::AnyBuffer> glogw, ffi::Result<ffi::AnyBuffer> gdconst) {
  jaxgenus::RasterConfig cfg;
  const Attrs a{height, width, want_cov, n_attr, attr_planes, want_depth, sigma, gamma, sharpness, background};
  if (ffi::Error e = CheckAttrs("raster_backward", a, &cfg); e.failure()) return e;
  ShapeCheck chk("raster_backward");
  int64_t nf = 0;
  if (ffi::Error e = CheckFaces(chk, cfg, v, plane, qrange, attr, logw, valid, dconst, &nf); e.failure()) return e;
  const ffi::DataType dt = v.element_type();
  const int64_t H = height, W = width, C = cfg.n_blend(), A = n_attr * cfg.attr_stride();
  chk("blend", blend.dimensions(), {H, W, C}, blend.element_type(), dt) &&
      chk("mlw", mlw.dimensions(), {H, W}, mlw.element_type(), dt) &&
      chk("g_cov", g_cov.dimensions(), {H, W}, g_cov.element_type(), dt) &&
      chk("g_blend", g_blend.dimensions(), {H, W, C}, g_blend.element_type(), dt) &&
      chk("grad v", gv->dimensions(), {nf, 3, 2}, gv->element_type(), dt) &&
      chk("grad plane", gplane->dimensions(), {nf, 3}, gplane->element_type(), dt) &&
      chk("grad qrange", gqrange->dimensions(), {nf, 2}, gqrange->element_type(), dt) &&
      chk("grad attr", gattr->dimensions(), {nf, A}, gattr->element_type(), dt) &&
      chk("grad logw", glogw->dimensions(), {nf}, glogw->element_type(), dt) &&
      chk("grad dconst", gdconst->dimensions(), {2}, gdconst->element_type(), dt);
  if (ffi::Error e = chk.error(); e.failure()) return e;
  std::string msg;
  jaxgenus::Status s;
  if (dt == ffi::DataType::F32) {
    s = Backward(cfg, Faces<float>(chk.views(), nf, v, plane, qrange, attr, logw, valid, dconst), blend, mlw,
                 g_cov, g_blend, gv, gplane, gqrange, gattr, glogw, gdconst, &msg);
  } else {
    s = Backward(cfg, Faces<double>(chk.views(), nf, v, plane, qrange, attr, logw, valid, dconst), blend, mlw,
                 g_cov, g_blend, gv, gplane, gqrange, gattr, glogw, gdconst, &msg);
  }
  return Finish(s, msg);
}

#define JG_RASTER_ATTRS(b)              \
  b.Attr<int64_t>("height")             \
      .Attr<int64_t>("width")           \
      .Attr<double>("sigma")            \
      .Attr<double>("gamma")            \
      .Attr<double>("sharpness")        \
      .Attr<int64_t>("want_cov")        \
      .Attr<int64_t>("n_attr")          \
      .Attr<int64_t>("attr_planes")     \
      .Attr<int64_t>("want_depth")      \
      .Attr<ffi::Span<const double>>("background")

// The per-face operands both handlers take first: v, plane, qrange, attr, logw, valid, dconst.
#define JG_RASTER_FACES(bind)            \
  bind.Arg<ffi::AnyBuffer>()             \
      .Arg<ffi::AnyBuffer>()             \
      .Arg<ffi::AnyBuffer>()             \
      .Arg<ffi::AnyBuffer>()             \
      .Arg<ffi::AnyBuffer>()             \
      .Arg<ffi::Buffer<ffi::PRED>>()     \
      .Arg<ffi::AnyBuffer>()

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgRasterForward, ForwardImpl,
                              JG_RASTER_ATTRS(JG_RASTER_FACES(ffi::Ffi::Bind()))
                                  .Ret<ffi::AnyBuffer>()   // cov
                                  .Ret<ffi::AnyBuffer>()   // blend
                                  .Ret<ffi::AnyBuffer>());  // mlw

XLA_FFI_DEFINE_HANDLER_SYMBOL(JgRasterBackward, BackwardImpl,
                              JG_RASTER_ATTRS(JG_RASTER_FACES(ffi::Ffi::Bind())
                                                  .Arg<ffi::AnyBuffer>()   // blend
                                                  .Arg<ffi::AnyBuffer>()   // mlw
                                                  .Arg<ffi::AnyBuffer>()   // g_cov
                                                  .Arg<ffi::AnyBuffer>())  // g_blend
                                  .Ret<ffi::AnyBuffer>()   // d v
                                  .Ret<ffi::AnyBuffer>()   // d plane
                                  .Ret<ffi::AnyBuffer>()   // d qrange
                                  .Ret<ffi::AnyBuffer>()   // d attr
                                  .Ret<ffi::AnyBuffer>()   // d logw
                                  .Ret<ffi::AnyBuffer>());  // d dconst
