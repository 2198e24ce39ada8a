// oneDNN convolutions and matrix products for XLA's CPU backend, as XLA FFI handlers (agentax.kernels
// calls them).
//
// Three convolution handlers, every array channels-last and every convolution VALID (no padding):
//   agentax_conv_fwd       x [..., N, H, W, C], w [..., KH, KW, C, O]   -> y  [..., N, OH, OW, O]
//   agentax_conv_bwd_data  dy [..., N, OH, OW, O], w [..., KH, KW, C, O] -> dx [..., N, H, W, C]
//   agentax_conv_bwd_w     x [..., N, H, W, C], dy [..., N, OH, OW, O]  -> dw [..., KH, KW, C, O]
// Inputs are f32 or bf16 (bf16 runs on AMX where the CPU has it), outputs f32 or bf16. The leading
// dimensions "..." are vmap's (jax.ffi.ffi_call with vmap_method="expand_dims": every input has the
// same number of them, each either the batch size or 1). Where the weights' leading dimensions are
// all 1 the batch folds into N (one large convolution); otherwise one convolution per batch entry.
//
// One matrix-product handler (the dense layers' forward pass and both gradients), all float32:
//   agentax_matmul  a [..., M, K] (stored [..., K, M] with transpose_a), b [..., K, N] (stored
//                   [..., N, K] with transpose_b) -> c [..., M, N]; bf16 != 0 computes in bfloat16
//                   (oneDNN's bf16 fpmath mode: AMX where the CPU has it), accumulating in float32.
//
// Building a oneDNN primitive (choosing its implementation, generating its code) costs far more than
// running one of these small convolutions, so each is built once per shape and kept in a cache.

#include <omp.h>

#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "oneapi/dnnl/dnnl.hpp"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;
using dt = dnnl::memory::data_type;
using tag = dnnl::memory::format_tag;
using dims = dnnl::memory::dims;

namespace {

std::atomic<int> g_threads{0};  // 0: OpenMP's own default

dnnl::engine& cpu_engine() {
  static dnnl::engine engine(dnnl::engine::kind::cpu, 0);
  return engine;
}

dnnl::stream& thread_stream() {
  thread_local dnnl::stream stream(cpu_engine());
  return stream;
}

// The scratchpad every primitive asks for (user mode), one per calling thread so that two XLA
// threads can run convolutions at once.
void* scratchpad(size_t bytes) {
  thread_local std::vector<char> buffer;
  if (buffer.size() < bytes) buffer.resize(bytes);
  return buffer.data();
}

// The transient buffers a call needs (bf16 or blocked copies of the weights), per calling thread.
struct Workspace {
  std::vector<std::vector<char>> slots;
  void* get(size_t slot, size_t bytes) {
    if (slots.size() <= slot) slots.resize(slot + 1);
    if (slots[slot].size() < bytes) slots[slot].resize(bytes);
    return slots[slot].data();
  }
};

Workspace& workspace() {
  thread_local Workspace ws;
  return ws;
}

dt to_dnnl(ffi::DataType type) {
  switch (type) {
    case ffi::DataType::F32:
      return dt::f32;
    case ffi::DataType::BF16:
      return dt::bf16;
    default:
      return dt::undef;
  }
}

// The geometry of one call: the 4-d convolution and its vmap batch.
struct Shape {
  int64_t n, h, w, c, kh, kw, o, oh, ow, sh, sw;
};

enum class Kind { kFwd, kBwdData, kBwdWeights };

// One cached convolution: its primitive and the reorders that bring the weights (or the weight
// gradient) between the caller's HWIO layout and the one the primitive chose.
struct Conv {
  dnnl::primitive prim;
  dnnl::memory::desc src_md, wei_md, dst_md;  // as the primitive wants them
  dnnl::memory::desc user_wei_md;             // HWIO, the caller's data type
  bool wei_reorder = false;
  dnnl::reorder wei_prim;
  dnnl::memory::desc scratch_md;
  std::string impl;  // oneDNN's name for the implementation it chose
};

dnnl::memory::desc hwio(const Shape& s, dt type) {
  // Logical dims OIHW; the layout HWIO (flax's kernel layout).
  return dnnl::memory::desc({s.o, s.c, s.kh, s.kw}, type, tag::hwio);
}

std::string key_of(Kind kind, const Shape& s, dt a, dt b, dt out) {
  std::string key;
  for (int64_t v : {int64_t(kind), s.n, s.h, s.w, s.c, s.kh, s.kw, s.o, s.sh, s.sw, int64_t(a), int64_t(b),
                    int64_t(out)}) {
    key += std::to_string(v);
    key += ',';
  }
  return key;
}

// Keeps primitive `Prim` of `pd` in `conv` with its memory descriptors (src, weights, dst as the
// primitive names them) and the user's HWIO weights.
template <typename Prim, typename PrimitiveDesc>
void keep(Conv& conv, const PrimitiveDesc& pd, const dnnl::memory::desc& src, const dnnl::memory::desc& wei,
          const dnnl::memory::desc& dst, const dnnl::memory::desc& user_wei) {
  conv.prim = Prim(pd);
  conv.src_md = src;
  conv.wei_md = wei;
  conv.dst_md = dst;
  conv.user_wei_md = user_wei;
  conv.scratch_md = pd.scratchpad_desc();
  conv.impl = pd.impl_info_str();
}

// Builds the primitive for `kind`; types: fwd (x, w, y), bwd data (dy, w, dx), bwd weights (x, dy, dw).
std::unique_ptr<Conv> build(Kind kind, const Shape& s, dt a, dt b, dt out) {
  auto& eng = cpu_engine();
  dims src_dims{s.n, s.c, s.h, s.w}, dst_dims{s.n, s.o, s.oh, s.ow}, wei_dims{s.o, s.c, s.kh, s.kw};
  dims strides{s.sh, s.sw}, pad{0, 0};
  dnnl::primitive_attr attr;
  attr.set_scratchpad_mode(dnnl::scratchpad_mode::user);
  auto conv = std::make_unique<Conv>();
  dt compute = a;  // the type the convolution computes in: its activations'
  auto any_wei = dnnl::memory::desc(wei_dims, compute, tag::any);
  auto alg = dnnl::algorithm::convolution_direct;
  if (kind == Kind::kFwd) {
    auto src = dnnl::memory::desc(src_dims, a, tag::nhwc);
    auto dst = dnnl::memory::desc(dst_dims, out, tag::nhwc);
    auto pd = dnnl::convolution_forward::primitive_desc(eng, dnnl::prop_kind::forward_training, alg, src,
                                                        any_wei, dst, strides, pad, pad, attr);
    keep<dnnl::convolution_forward>(*conv, pd, pd.src_desc(), pd.weights_desc(), pd.dst_desc(), hwio(s, b));
  } else {
    // oneDNN's backward primitives take a forward one as a hint.
    dt src_type = kind == Kind::kBwdData ? out : a;
    dt dst_type = kind == Kind::kBwdData ? a : b;
    auto src = dnnl::memory::desc(src_dims, src_type, tag::nhwc);
    auto dst = dnnl::memory::desc(dst_dims, dst_type, tag::nhwc);
    dt wei_type = kind == Kind::kBwdData ? compute : out;  // bwd data: the weights reordered to it
    auto wei = dnnl::memory::desc(wei_dims, wei_type, tag::any);
    auto hint_dst = dnnl::memory::desc(dst_dims, compute, tag::nhwc);
    auto hint_src = dnnl::memory::desc(src_dims, compute, tag::nhwc);
    auto hint = dnnl::convolution_forward::primitive_desc(eng, dnnl::prop_kind::forward_training, alg,
                                                          hint_src, any_wei, hint_dst, strides, pad, pad);
    if (kind == Kind::kBwdData) {
      auto pd = dnnl::convolution_backward_data::primitive_desc(eng, alg, src, wei, dst, strides, pad, pad,
                                                                hint, attr);
      keep<dnnl::convolution_backward_data>(*conv, pd, pd.diff_src_desc(), pd.weights_desc(),
                                            pd.diff_dst_desc(), hwio(s, b));
    } else {
      auto pd = dnnl::convolution_backward_weights::primitive_desc(eng, alg, src, wei, dst, strides, pad,
                                                                   pad, hint, attr);
      keep<dnnl::convolution_backward_weights>(*conv, pd, pd.src_desc(), pd.diff_weights_desc(),
                                               pd.diff_dst_desc(), hwio(s, out));
    }
  }
  conv->wei_reorder = conv->wei_md != conv->user_wei_md;
  if (conv->wei_reorder) {
    if (kind == Kind::kBwdWeights) {
      conv->wei_prim = dnnl::reorder(dnnl::reorder::primitive_desc(eng, conv->wei_md, eng, conv->user_wei_md));
    } else {
      conv->wei_prim = dnnl::reorder(dnnl::reorder::primitive_desc(eng, conv->user_wei_md, eng, conv->wei_md));
    }
  }
  return conv;
}

// The primitive `make()` builds for `key`, built once and kept (one cache per primitive type).
template <typename T, typename Make>
T& kept(const std::string& key, Make make) {
  static std::mutex mutex;
  static std::unordered_map<std::string, std::unique_ptr<T>> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto& slot = cache[key];
  if (!slot) slot = make();
  return *slot;
}

Conv& cached(Kind kind, const Shape& s, dt a, dt b, dt out) {
  return kept<Conv>(key_of(kind, s, a, b, out), [&] { return build(kind, s, a, b, out); });
}

// Runs one 4-d convolution on raw pointers: fwd (x, w) -> y, bwd data (dy, w) -> dx,
// bwd weights (x, dy) -> dw; `a`, `b`, `r` are the first input, the second input and the result.
void run(Kind kind, Conv& conv, void* a, void* b, void* r) {
  auto& eng = cpu_engine();
  auto& strm = thread_stream();
  dnnl::memory scratch(conv.scratch_md, eng, scratchpad(conv.scratch_md.get_size() + 64));
  if (kind == Kind::kBwdWeights) {
    dnnl::memory src(conv.src_md, eng, a), dst(conv.dst_md, eng, b);
    dnnl::memory user_wei(conv.user_wei_md, eng, r);
    dnnl::memory wei = conv.wei_reorder
                           ? dnnl::memory(conv.wei_md, eng, workspace().get(0, conv.wei_md.get_size()))
                           : user_wei;
    conv.prim.execute(strm, {{DNNL_ARG_SRC, src},
                             {DNNL_ARG_DIFF_DST, dst},
                             {DNNL_ARG_DIFF_WEIGHTS, wei},
                             {DNNL_ARG_SCRATCHPAD, scratch}});
    if (conv.wei_reorder) conv.wei_prim.execute(strm, wei, user_wei);
  } else {
    dnnl::memory user_wei(conv.user_wei_md, eng, b);
    dnnl::memory wei = user_wei;
    if (conv.wei_reorder) {
      wei = dnnl::memory(conv.wei_md, eng, workspace().get(0, conv.wei_md.get_size()));
      conv.wei_prim.execute(strm, user_wei, wei);
    }
    if (kind == Kind::kFwd) {
      dnnl::memory src(conv.src_md, eng, a), dst(conv.dst_md, eng, r);
      conv.prim.execute(
          strm, {{DNNL_ARG_SRC, src}, {DNNL_ARG_WEIGHTS, wei}, {DNNL_ARG_DST, dst}, {DNNL_ARG_SCRATCHPAD, scratch}});
    } else {
      dnnl::memory diff_dst(conv.dst_md, eng, a), diff_src(conv.src_md, eng, r);
      conv.prim.execute(strm, {{DNNL_ARG_DIFF_DST, diff_dst},
                               {DNNL_ARG_WEIGHTS, wei},
                               {DNNL_ARG_DIFF_SRC, diff_src},
                               {DNNL_ARG_SCRATCHPAD, scratch}});
    }
  }
  strm.wait();
}

// The leading (vmap) dimensions of an array whose last `core` dimensions are the convolution's.
std::vector<int64_t> lead_of(ffi::Span<const int64_t> d, size_t core) {
  return std::vector<int64_t>(d.begin(), d.end() - core);
}

int64_t product(const std::vector<int64_t>& v) {
  int64_t p = 1;
  for (int64_t x : v) p *= x;
  return p;
}

// The offset (in elements of one batch entry) of output batch entry `i` in an input whose leading
// dims are `lead` (each equal to `out_lead`'s or 1: broadcast).
int64_t broadcast_index(int64_t i, const std::vector<int64_t>& lead, const std::vector<int64_t>& out_lead) {
  int64_t index = 0, stride = 1;
  for (size_t d = out_lead.size(); d-- > 0;) {
    int64_t coord = i % out_lead[d];
    i /= out_lead[d];
    if (lead[d] != 1) index += coord * stride;
    stride *= lead[d];
  }
  return index;
}

// Shared by the three handlers: `first` and `second` are the inputs, `result` the output, each with
// `core` dims (4) after the vmap dims; `x_first`: which of the four-d arrays carries N, H, W, C.
ffi::Error convolve(Kind kind, ffi::AnyBuffer first, ffi::AnyBuffer second, ffi::Result<ffi::AnyBuffer> result,
                    int64_t sh, int64_t sw) {
  dt a = to_dnnl(first.element_type()), b = to_dnnl(second.element_type());
  dt r = to_dnnl(result->element_type());
  if (a == dt::undef || b == dt::undef || r == dt::undef)
    return ffi::Error::InvalidArgument("agentax conv: arrays must be float32 or bfloat16");
  auto fd = first.dimensions(), sd = second.dimensions(), rd = result->dimensions();
  if (fd.size() < 4 || fd.size() != sd.size() || fd.size() != rd.size())
    return ffi::Error::InvalidArgument("agentax conv: arrays of rank 4 plus the same vmap dims expected");
  size_t lead_rank = fd.size() - 4;
  auto fl = lead_of(fd, 4), sl = lead_of(sd, 4), rl = lead_of(rd, 4);
  for (size_t d = 0; d < lead_rank; ++d) {
    if ((fl[d] != rl[d] && fl[d] != 1) || (sl[d] != rl[d] && sl[d] != 1))
      return ffi::Error::InvalidArgument("agentax conv: vmap dims do not broadcast");
  }
  // Pick the 4-d geometry out of whichever arrays hold it.
  const int64_t* act;  // [N, H, W, C]
  const int64_t* wei;  // [KH, KW, C, O]
  const int64_t* out;  // [N, OH, OW, O]
  if (kind == Kind::kFwd) {
    act = fd.begin() + lead_rank, wei = sd.begin() + lead_rank, out = rd.begin() + lead_rank;
  } else if (kind == Kind::kBwdData) {
    out = fd.begin() + lead_rank, wei = sd.begin() + lead_rank, act = rd.begin() + lead_rank;
  } else {
    act = fd.begin() + lead_rank, out = sd.begin() + lead_rank, wei = rd.begin() + lead_rank;
  }
  Shape s{act[0], act[1], act[2], act[3], wei[0], wei[1], wei[3], out[1], out[2], sh, sw};
  if (wei[2] != s.c || out[3] != s.o || out[0] != s.n || (s.h - s.kh) / sh + 1 != s.oh ||
      (s.w - s.kw) / sw + 1 != s.ow)
    return ffi::Error::InvalidArgument("agentax conv: shapes of a VALID convolution expected");
  int64_t batch = product(rl);
  // The weights (fwd, bwd data) shared by every batch entry: fold the batch into N.
  bool fold = kind != Kind::kBwdWeights && product(sl) == 1 && product(fl) == batch;
  Shape one = s;
  if (fold) one.n *= batch;
  try {
    int threads = g_threads.load();
    if (threads > 0) omp_set_num_threads(threads);
    Conv& conv = cached(kind, one, a, b, r);
    if (fold) {
      run(kind, conv, first.untyped_data(), second.untyped_data(), result->untyped_data());
      return ffi::Error::Success();
    }
    size_t first_bytes = first.size_bytes() / product(fl), second_bytes = second.size_bytes() / product(sl);
    size_t result_bytes = result->size_bytes() / batch;
    for (int64_t i = 0; i < batch; ++i) {
      char* f = static_cast<char*>(first.untyped_data()) + broadcast_index(i, fl, rl) * first_bytes;
      char* g = static_cast<char*>(second.untyped_data()) + broadcast_index(i, sl, rl) * second_bytes;
      char* o = static_cast<char*>(result->untyped_data()) + i * result_bytes;
      run(kind, conv, f, g, o);
    }
  } catch (const dnnl::error& e) {
    return ffi::Error::Internal(std::string("agentax conv (oneDNN, ") + key_of(kind, one, a, b, r) +
                                "): " + e.what());
  }
  return ffi::Error::Success();
}

ffi::Error Fwd(ffi::AnyBuffer x, ffi::AnyBuffer w, ffi::Result<ffi::AnyBuffer> y, int64_t sh, int64_t sw) {
  return convolve(Kind::kFwd, x, w, y, sh, sw);
}
ffi::Error BwdData(ffi::AnyBuffer dy, ffi::AnyBuffer w, ffi::Result<ffi::AnyBuffer> dx, int64_t sh, int64_t sw) {
  return convolve(Kind::kBwdData, dy, w, dx, sh, sw);
}
ffi::Error BwdWeights(ffi::AnyBuffer x, ffi::AnyBuffer dy, ffi::Result<ffi::AnyBuffer> dw, int64_t sh,
                      int64_t sw) {
  return convolve(Kind::kBwdWeights, x, dy, dw, sh, sw);
}

// One cached matrix product [M, K] @ [K, N] (transposes as strides) and its scratchpad.
struct Matmul {
  dnnl::matmul prim;
  dnnl::memory::desc a_md, b_md, c_md, scratch_md;
  std::string impl;
};

// A row-major [rows, cols] float32 matrix, or its transpose stored row-major ([cols, rows]).
dnnl::memory::desc matrix(int64_t rows, int64_t cols, bool transposed) {
  return dnnl::memory::desc({rows, cols}, dt::f32, transposed ? dims{1, rows} : dims{cols, 1});
}

std::unique_ptr<Matmul> build_matmul(int64_t m, int64_t k, int64_t n, bool ta, bool tb, bool bf16) {
  dnnl::primitive_attr attr;
  attr.set_scratchpad_mode(dnnl::scratchpad_mode::user);
  if (bf16) attr.set_fpmath_mode(dnnl::fpmath_mode::bf16);
  auto mm = std::make_unique<Matmul>();
  mm->a_md = matrix(m, k, ta), mm->b_md = matrix(k, n, tb), mm->c_md = matrix(m, n, false);
  auto pd = dnnl::matmul::primitive_desc(cpu_engine(), mm->a_md, mm->b_md, mm->c_md, attr);
  mm->prim = dnnl::matmul(pd);
  mm->scratch_md = pd.scratchpad_desc();
  mm->impl = pd.impl_info_str();
  return mm;
}

Matmul& cached_matmul(int64_t m, int64_t k, int64_t n, bool ta, bool tb, bool bf16) {
  std::string key;
  for (int64_t v : {m, k, n, int64_t(ta), int64_t(tb), int64_t(bf16)}) key += std::to_string(v) + ',';
  return kept<Matmul>(key, [&] { return build_matmul(m, k, n, ta, tb, bf16); });
}

void run_matmul(Matmul& mm, void* a, void* b, void* c) {
  auto& eng = cpu_engine();
  auto& strm = thread_stream();
  dnnl::memory scratch(mm.scratch_md, eng, scratchpad(mm.scratch_md.get_size() + 64));
  dnnl::memory am(mm.a_md, eng, a), bm(mm.b_md, eng, b), cm(mm.c_md, eng, c);
  mm.prim.execute(strm, {{DNNL_ARG_SRC, am}, {DNNL_ARG_WEIGHTS, bm}, {DNNL_ARG_DST, cm}, {DNNL_ARG_SCRATCHPAD, scratch}});
  strm.wait();
}

ffi::Error MatmulHandler(ffi::Buffer<ffi::F32> a, ffi::Buffer<ffi::F32> b, ffi::ResultBuffer<ffi::F32> c,
                         int64_t transpose_a, int64_t transpose_b, int64_t bf16) {
  auto ad = a.dimensions(), bd = b.dimensions(), cd = c->dimensions();
  if (ad.size() < 2 || ad.size() != bd.size() || ad.size() != cd.size())
    return ffi::Error::InvalidArgument("agentax matmul: arrays of rank 2 plus the same vmap dims expected");
  size_t r = ad.size();
  auto al = lead_of(ad, 2), bl = lead_of(bd, 2), cl = lead_of(cd, 2);
  for (size_t d = 0; d + 2 < r; ++d) {
    if ((al[d] != cl[d] && al[d] != 1) || (bl[d] != cl[d] && bl[d] != 1))
      return ffi::Error::InvalidArgument("agentax matmul: vmap dims do not broadcast");
  }
  int64_t m = transpose_a ? ad[r - 1] : ad[r - 2], k = transpose_a ? ad[r - 2] : ad[r - 1];
  int64_t n = transpose_b ? bd[r - 2] : bd[r - 1];
  if ((transpose_b ? bd[r - 1] : bd[r - 2]) != k || cd[r - 2] != m || cd[r - 1] != n)
    return ffi::Error::InvalidArgument("agentax matmul: shapes [M, K] @ [K, N] -> [M, N] expected");
  int64_t batch = product(cl);
  // b shared by every batch entry and a not transposed: the batch folds into M (one larger product).
  bool fold = !transpose_a && product(bl) == 1 && product(al) == batch;
  try {
    int threads = g_threads.load();
    if (threads > 0) omp_set_num_threads(threads);
    Matmul& mm = cached_matmul(fold ? m * batch : m, k, n, transpose_a, transpose_b, bf16 != 0);
    if (fold) {
      run_matmul(mm, a.untyped_data(), b.untyped_data(), c->untyped_data());
      return ffi::Error::Success();
    }
    for (int64_t i = 0; i < batch; ++i) {
      float* ai = a.typed_data() + broadcast_index(i, al, cl) * m * k;
      float* bi = b.typed_data() + broadcast_index(i, bl, cl) * k * n;
      run_matmul(mm, ai, bi, c->typed_data() + i * m * n);
    }
  } catch (const dnnl::error& e) {
    return ffi::Error::Internal(std::string("agentax matmul (oneDNN): ") + e.what());
  }
  return ffi::Error::Success();
}

}  // namespace

#define AGENTAX_CONV_BINDING                                                                      \
  ffi::Ffi::Bind().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Attr<int64_t>( \
      "stride_h").Attr<int64_t>("stride_w")

XLA_FFI_DEFINE_HANDLER_SYMBOL(agentax_conv_fwd, Fwd, AGENTAX_CONV_BINDING);
XLA_FFI_DEFINE_HANDLER_SYMBOL(agentax_conv_bwd_data, BwdData, AGENTAX_CONV_BINDING);
XLA_FFI_DEFINE_HANDLER_SYMBOL(agentax_conv_bwd_w, BwdWeights, AGENTAX_CONV_BINDING);
XLA_FFI_DEFINE_HANDLER_SYMBOL(agentax_matmul, MatmulHandler,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Attr<int64_t>("transpose_a")
                                  .Attr<int64_t>("transpose_b")
                                  .Attr<int64_t>("bf16"));

// Writes oneDNN's name for an implementation into the caller's buffer of `size` bytes; returns 1.
int copy_name(const std::string& impl, char* name, int size) {
  std::strncpy(name, impl.c_str(), size - 1);
  name[size - 1] = 0;
  return 1;
}

extern "C" {
// The OpenMP threads oneDNN runs each convolution on (0: OpenMP's default, the CPUs it saw at start).
void agentax_conv_set_threads(int threads) { g_threads.store(threads); }
int agentax_conv_version() { return dnnl_version()->major * 100 + dnnl_version()->minor; }
// Which implementation oneDNN chose for a convolution (kind 0 fwd, 1 bwd data, 2 bwd weights) of
// this geometry, computing in bf16 or f32 (for the benchmarks' notes); 0 if it cannot build one.
int agentax_conv_impl(int kind, int64_t n, int64_t h, int64_t w, int64_t c, int64_t kh, int64_t kw, int64_t o,
                      int64_t stride, int bf16, char* name, int size) {
  try {
    Shape s{n, h, w, c, kh, kw, o, (h - kh) / stride + 1, (w - kw) / stride + 1, stride, stride};
    dt type = bf16 ? dt::bf16 : dt::f32;
    return copy_name(cached(Kind(kind), s, type, type, dt::f32).impl, name, size);
  } catch (const dnnl::error&) {
    return 0;
  }
}
// The same for a matrix product [M, K] @ [K, N] (for the benchmarks' notes).
int agentax_matmul_impl(int64_t m, int64_t k, int64_t n, int bf16, char* name, int size) {
  try {
    return copy_name(cached_matmul(m, k, n, false, false, bf16 != 0).impl, name, size);
  } catch (const dnnl::error&) {
    return 0;
  }
}
}
