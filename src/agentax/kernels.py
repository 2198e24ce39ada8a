"""oneDNN on the CPU: the Nature CNN's convolutions, its dense layer and their gradients as XLA FFI calls.

XLA's CPU convolutions are what bound the Atari learners. :func:`conv2d` calls oneDNN
(``csrc/onednn_conv.cc``, compiled by ``make`` into ``_onednn_conv.so`` beside this file) for the
forward convolution, the input gradient and the weight gradient, and :func:`dense` for the 3136 → 512
layer's product and both of its gradients; on any other platform, and with the backend ``xla``, they
are ``lax.conv_general_dilated`` and ``jnp.matmul`` exactly. Every function takes its backend as an
argument (one of :data:`BACKENDS`), chosen before tracing by the entry point
(:func:`agentax.kernel_choice.backend_for`) and handed down to the networks like the runner's
``loop``; nothing here reads the environment or measures.

- ``xla``: XLA's convolutions and products (the golden numbers were made with them);
- ``onednn``: oneDNN in float32 (fails loudly where the library could not be loaded);
- ``onednn-bf16``: oneDNN computing in bfloat16 (AMX on Sapphire Rapids, AVX-512 BF16 on Zen 4);
  inputs, weights and gradients stay float32 outside, rounded to bfloat16 inside, accumulated in
  float32.

The networks' other products take a precision (one of :data:`PRECISIONS`, chosen by the entry point
as the backend is, :func:`agentax.kernel_choice.precision_choice`): :func:`matmul` and
:func:`dot_general_for` give ``bf16`` products (bfloat16 operands, float32 accumulation, float32
out) computed by XLA (``bf16``) or by oneDNN's matmul (``bf16-onednn``), or leave XLA's float32
ones exactly as they were.

``AGENTAX_CONV_THREADS`` sets oneDNN's OpenMP threads (default 1; ``OMP_WAIT_POLICY`` defaults to
``PASSIVE``, so that idle OpenMP threads sleep instead of spinning on a core that XLA or an env
thread needs): with one core busy elsewhere, a DQN update took 30.4 ms with two threads against 28.7
with one in float32, and 276 ms against 19 in bfloat16 (oneDNN 3.2).

Under ``jax.vmap`` (seeds vmapped by the compiled runner) the FFI calls get the batch as leading
dimensions (``vmap_method="expand_dims"``): with shared weights it folds into the convolution's
batch, with one set of weights per seed the kernel runs one convolution per seed.
"""

from __future__ import annotations

import ctypes
import functools
import os
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from agentax import _xla
from agentax.errors import UsageError

LIBRARY = Path(__file__).with_name("_onednn_conv.so")
"""Where ``make`` puts the compiled kernel (``AGENTAX_ONEDNN_LIB`` names another)."""
TARGETS = ("agentax_conv_fwd", "agentax_conv_bwd_data", "agentax_conv_bwd_w", "agentax_matmul")
BACKENDS = ("xla", "onednn", "onednn-bf16")
"""The convolution backends a network can be handed."""
NHWC = ("NHWC", "HWIO", "NHWC")


@functools.cache
def _load() -> tuple[ctypes.CDLL | None, str]:
    """The kernel library with its FFI targets registered for the CPU, or None and why not."""
    path = Path(os.environ.get("AGENTAX_ONEDNN_LIB", LIBRARY))
    if not path.is_file():
        return None, f"{path} is missing (make builds it from csrc/onednn_conv.cc)"
    # OpenMP threads that sleep between convolutions rather than spin: spinning ones take the core
    # from XLA's own thread and the env threads (read when libgomp starts, so set before loading).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    try:
        library = ctypes.CDLL(str(path))
    except OSError as error:
        return None, f"{path} does not load: {error}"
    for name in TARGETS:
        jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(library, name)), platform="cpu")
    threads = os.environ.get("AGENTAX_CONV_THREADS", "1")
    if not threads.isdigit() or int(threads) < 1:
        raise UsageError(f"AGENTAX_CONV_THREADS={threads!r}: give a whole number of threads, at least 1")
    library.agentax_conv_set_threads(ctypes.c_int(int(threads)))
    return library, ""


def available() -> bool:
    """Whether the oneDNN kernel loaded (see :func:`unavailable_reason` when not)."""
    return _load()[0] is not None


def unavailable_reason() -> str:
    """Why the oneDNN kernel is not available ("" when it is)."""
    return _load()[1]


def implementation(kind: str, shape: tuple[int, ...], kernel: tuple[int, ...], bf16: bool) -> str:
    """oneDNN's name for the implementation it picks (``kind``: fwd, bwd_data, bwd_w) for input
    ``shape`` ``(N, H, W, C)`` and ``kernel`` ``(size, out_channels, stride)``, or (``kind`` matmul)
    for ``[M, K] @ [K, N]`` with ``shape`` ``(M, K)`` and ``kernel`` ``(N,)``: for the benchmark notes."""
    library = _load()[0]
    if library is None:
        return "unavailable"
    name = ctypes.create_string_buffer(128)
    if kind == "matmul":
        args = [ctypes.c_int64(v) for v in (*shape, *kernel)]
        found = library.agentax_matmul_impl(*args, ctypes.c_int(bf16), name, 128)
    else:
        size, out, stride = kernel
        args = [ctypes.c_int64(v) for v in (*shape[:3], shape[3], size, size, out, stride)]
        found = library.agentax_conv_impl(
            ctypes.c_int(("fwd", "bwd_data", "bwd_w").index(kind)), *args, ctypes.c_int(bf16), name, 128
        )
    return name.value.decode() if found else "none"


def xla_conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int]) -> jax.Array:
    """XLA's VALID convolution: ``x [N, H, W, C]``, ``w [KH, KW, C, O]`` → ``[N, OH, OW, O]``."""
    return lax.conv_general_dilated(x, w, stride, "VALID", dimension_numbers=NHWC)


def _call(target: str, out: jax.ShapeDtypeStruct, a: jax.Array, b: jax.Array, stride) -> jax.Array:
    call = jax.ffi.ffi_call(target, out, vmap_method="expand_dims")
    return call(a, b, stride_h=np.int64(stride[0]), stride_w=np.int64(stride[1]))


def _out_shape(x_shape, w_shape, stride) -> tuple[int, ...]:
    n, h, w, _ = x_shape
    kh, kw, _, o = w_shape
    return (n, (h - kh) // stride[0] + 1, (w - kw) // stride[1] + 1, o)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2, 3))
def _onednn_conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int], bf16: bool) -> jax.Array:
    return _onednn_forward(x, w, stride, bf16)[0]


def _compute(x: jax.Array, bf16: bool) -> jax.Array:
    """``x`` in the type the kernel computes in (the weights are converted inside, once per call)."""
    return x.astype(jnp.bfloat16) if bf16 else x


def _onednn_forward(x, w, stride, bf16):
    out = jax.ShapeDtypeStruct(_out_shape(x.shape, w.shape, stride), x.dtype)
    return _call("agentax_conv_fwd", out, _compute(x, bf16), w, stride), (x, w)


def _onednn_backward(stride, bf16, residuals, dy):
    x, w = residuals
    dyc = _compute(dy, bf16)
    # In bf16 the input gradient comes back in bf16 (oneDNN 3.2 has no bf16 -> f32 variant of it).
    dx = _call("agentax_conv_bwd_data", jax.ShapeDtypeStruct(x.shape, dyc.dtype), dyc, w, stride)
    dw = _call("agentax_conv_bwd_w", jax.ShapeDtypeStruct(w.shape, w.dtype), _compute(x, bf16), dyc, stride)
    return dx.astype(x.dtype), dw


_onednn_conv2d.defvjp(_onednn_forward, _onednn_backward)


def check(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and can run here, else a ``UsageError`` saying why."""
    if backend not in BACKENDS:
        raise UsageError(f"convolution backend {backend!r} is not one of {', '.join(BACKENDS)}")
    if backend != "xla" and not available():
        raise UsageError(
            f"the {backend} backend needs the oneDNN kernel, unavailable: {unavailable_reason()}"
        )
    return backend


def conv2d(x: jax.Array, w: jax.Array, stride: tuple[int, int], backend: str = "xla") -> jax.Array:
    """A VALID convolution ``x [N, H, W, C]`` (float32), ``w [KH, KW, C, O]`` → ``[N, OH, OW, O]``:
    oneDNN on the CPU where ``backend`` says so, XLA's on every other platform; differentiable."""
    stride = tuple(int(s) for s in stride)
    return _on_the_cpu(
        lambda x, w, bf16: _onednn_conv2d(x, w, stride, bf16),
        lambda x, w: xla_conv2d(x, w, stride),
        x,
        w,
        backend,
    )


def _on_the_cpu(onednn: Callable, xla: Callable, a: jax.Array, b: jax.Array, backend: str) -> jax.Array:
    """``onednn(a, b, bf16)`` on the CPU where ``backend`` is oneDNN's and both arrays are float32,
    ``xla(a, b)`` everywhere else (other platforms, ``xla``, other types)."""
    check(backend)
    if backend == "xla" or a.dtype != jnp.float32 or b.dtype != jnp.float32:
        return xla(a, b)
    bf16 = backend == "onednn-bf16"
    return lax.platform_dependent(a, b, cpu=lambda a, b: onednn(a, b, bf16), default=xla)


def _matmul(a: jax.Array, b: jax.Array, bf16: bool, transpose_a=False, transpose_b=False) -> jax.Array:
    """oneDNN's ``op(a) @ op(b)`` of float32 matrices (``op``: transposed where asked), computed in
    bfloat16 with ``bf16``."""
    m = a.shape[1] if transpose_a else a.shape[0]
    n = b.shape[0] if transpose_b else b.shape[1]
    call = jax.ffi.ffi_call(
        "agentax_matmul", jax.ShapeDtypeStruct((m, n), jnp.float32), vmap_method="expand_dims"
    )
    return call(
        a, b, transpose_a=np.int64(transpose_a), transpose_b=np.int64(transpose_b), bf16=np.int64(bf16)
    )


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _onednn_dense(x: jax.Array, w: jax.Array, bf16: bool) -> jax.Array:
    return _matmul(x, w, bf16)


def _onednn_dense_forward(x, w, bf16):
    return _matmul(x, w, bf16), (x, w)


def _onednn_dense_backward(bf16, residuals, dy):
    x, w = residuals
    return _matmul(dy, w, bf16, transpose_b=True), _matmul(x, dy, bf16, transpose_a=True)


_onednn_dense.defvjp(_onednn_dense_forward, _onednn_dense_backward)


def dense(x: jax.Array, w: jax.Array, backend: str = "xla", elsewhere: Callable = jnp.matmul) -> jax.Array:
    """``x [..., K] @ w [K, N]`` → ``[..., N]`` (float32): oneDNN on the CPU where ``backend`` says so
    (bfloat16 inside with ``onednn-bf16``, accumulated in float32), ``elsewhere`` (XLA's product) on
    every other platform and for other types; differentiable."""
    if w.ndim != 2:
        return jnp.matmul(x, w)

    def onednn(x, w, bf16):
        return _onednn_dense(x.reshape(-1, x.shape[-1]), w, bf16).reshape(*x.shape[:-1], w.shape[1])

    return _on_the_cpu(onednn, elsewhere, x, w, backend)


def dot_general(lhs, rhs, dimension_numbers, precision=None, preferred_element_type=None, *, backend="xla"):
    """``lax.dot_general``'s signature (flax ``nn.Dense(dot_general=...)``, through
    :func:`dot_general_with`): a dense layer's product (``lhs [..., K]`` contracted with a ``[K, N]``
    kernel, default precision) goes to :func:`dense` on ``backend``, every other one to
    ``lax.dot_general`` unchanged."""
    plain = (
        rhs.ndim == 2
        and dimension_numbers == (((lhs.ndim - 1,), (0,)), ((), ()))
        and precision is None
        and preferred_element_type is None
    )
    if plain:
        return dense(lhs, rhs, backend)
    return lax.dot_general(lhs, rhs, dimension_numbers, precision, preferred_element_type)


PRECISIONS = ("f32", "bf16", "bf16-onednn")
"""The precisions of the networks' products a network can be handed: ``f32`` (XLA's float32
products, the golden numbers'), ``bf16`` (:func:`bf16_matmul`: bfloat16 operands, float32 sums) or
``bf16-onednn`` (:func:`onednn_bf16_matmul`: the same products by oneDNN's matmul)."""


def _bf16_product(a: jax.Array, b: jax.Array, contract: tuple[tuple[int, ...], tuple[int, ...]]) -> jax.Array:
    """``a`` and ``b`` rounded to bfloat16 and contracted over ``contract``, summed in float32."""
    bf16 = jnp.bfloat16
    dimensions = (contract, ((), ()))
    return lax.dot_general(a.astype(bf16), b.astype(bf16), dimensions, preferred_element_type=jnp.float32)


@jax.custom_vjp
def bf16_matmul(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x [..., K] @ w [K, N]`` → float32 ``[..., N]`` with bfloat16 operands and float32 accumulation
    (one rounding of each operand; XLA's CPU backend hands it to YNNPACK's bf16 kernels, AMX or
    AVX512-BF16 where the CPU has them). Its gradients are products of the same kind: the incoming
    gradient is rounded to bfloat16 too, the gradients come out float32 (the parameters, their
    gradients and the optimizer's moments stay float32)."""
    return _bf16_product(x, w, ((x.ndim - 1,), (0,)))


def _bf16_matmul_forward(x, w):
    return bf16_matmul(x, w), (x.astype(jnp.bfloat16), w.astype(jnp.bfloat16))


def _bf16_matmul_backward(residuals, dy):
    x, w = residuals  # bf16 [..., K], [K, N]; dy float32 [..., N]
    dx = _bf16_product(dy, w, ((dy.ndim - 1,), (1,)))  # [..., K]
    rows = x.reshape(-1, x.shape[-1])
    dw = _bf16_product(rows, dy.reshape(-1, dy.shape[-1]), ((0,), (0,)))  # [K, N]
    return dx, dw


bf16_matmul.defvjp(_bf16_matmul_forward, _bf16_matmul_backward)


def onednn_bf16_matmul(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x [..., K] @ w [K, N]`` → float32 ``[..., N]`` and its gradients by oneDNN's matmul on the CPU,
    bfloat16 arithmetic allowed (``fpmath_mode::bf16``: its AMX or AVX512-BF16 kernels, float32 sums;
    oneDNN keeps float32 where those do not pay, e.g. a few rows). At SAC's 256 × 256 × 256 it took a
    third of XLA's bf16 product's time forward and a quarter forward and backward (Intel Xeon with
    AMX). XLA's :func:`bf16_matmul` where the kernel is not built and on other platforms."""
    if w.ndim != 2 or not available():
        return bf16_matmul(x, w)
    return dense(x, w, "onednn-bf16", elsewhere=bf16_matmul)


BF16_PRODUCTS: dict[str, Callable] = {"bf16": bf16_matmul, "bf16-onednn": onednn_bf16_matmul}
"""The dense product of each bf16 precision."""


def matmul(x: jax.Array, w: jax.Array, precision: str = "f32") -> jax.Array:
    """``x [..., K] @ w [K, N]`` → ``[..., N]`` in ``precision``: ``x @ w`` exactly for ``f32``, the
    precision's product (:data:`BF16_PRODUCTS`) for the others."""
    return x @ w if check_precision(precision) == "f32" else BF16_PRODUCTS[precision](x, w)


def bf16_dot_general(
    lhs, rhs, dimension_numbers, precision=None, preferred_element_type=None, *, product=bf16_matmul
):
    """``lax.dot_general``'s signature for ``nn.Dense(dot_general=...)``: a dense layer's product
    (``lhs [..., K]`` contracted with a ``[K, N]`` kernel) is ``product`` (one of
    :data:`BF16_PRODUCTS`); any other contraction gets bfloat16 operands and float32 sums without the
    custom gradient."""
    if rhs.ndim == 2 and dimension_numbers == (((lhs.ndim - 1,), (0,)), ((), ())):
        return product(lhs, rhs)
    bf16 = jnp.bfloat16
    return lax.dot_general(
        lhs.astype(bf16), rhs.astype(bf16), dimension_numbers, precision, preferred_element_type=jnp.float32
    )


def dot_general_for(precision: str) -> Callable | None:
    """``nn.Dense``'s ``dot_general`` for ``precision``: None (flax's own ``lax.dot_general``, so
    float32 networks trace exactly as before) for ``f32``, :func:`bf16_dot_general` with the
    precision's product for the others."""
    if check_precision(precision) == "f32":
        return None
    return functools.partial(bf16_dot_general, product=BF16_PRODUCTS[precision])


def exportable(precision: str) -> str:
    """The precision of ``precision``'s products in a program that leaves the process (ONNX or
    StableHLO, where oneDNN's FFI calls exist in neither format): ``bf16`` for ``bf16-onednn``."""
    return "bf16" if precision == "bf16-onednn" else precision


def check_precision(precision: str) -> str:
    """``precision`` if it is one of :data:`PRECISIONS`, else a ``UsageError`` naming them."""
    if precision not in PRECISIONS:
        raise UsageError(f"unknown precision {precision!r}; choose from {', '.join(PRECISIONS)}")
    return precision


def conv_general_dilated(
    lhs,
    rhs,
    window_strides,
    padding,
    lhs_dilation=None,
    rhs_dilation=None,
    dimension_numbers=None,
    feature_group_count=1,
    precision=None,
    *,
    backend="xla",
):
    """``lax.conv_general_dilated``'s signature (flax ``nn.Conv(conv_general_dilated=...)``, through
    :func:`conv_general_dilated_with`): the convolutions :func:`conv2d` covers (2-d, VALID,
    NHWC/HWIO, no dilation or groups, default precision) go to it on ``backend``, every other one to
    ``lax.conv_general_dilated`` unchanged."""
    plain = (
        lhs.ndim == 4
        and padding in ("VALID", ((0, 0), (0, 0)), [(0, 0), (0, 0)])
        and all(d in (None, (1, 1), [1, 1]) for d in (lhs_dilation, rhs_dilation))
        and feature_group_count == 1
        and precision is None
        and dimension_numbers == lax.conv_dimension_numbers(lhs.shape, rhs.shape, NHWC)
    )
    if plain:
        return conv2d(lhs, rhs, window_strides, backend)
    return lax.conv_general_dilated(
        lhs,
        rhs,
        window_strides,
        padding,
        lhs_dilation=lhs_dilation,
        rhs_dilation=rhs_dilation,
        dimension_numbers=dimension_numbers,
        feature_group_count=feature_group_count,
        precision=precision,
    )


def dot_general_with(backend: str) -> Callable:
    """:func:`dot_general` on ``backend``, for ``nn.Dense(dot_general=...)``."""
    return functools.partial(dot_general, backend=backend)


def conv_general_dilated_with(backend: str) -> Callable:
    """:func:`conv_general_dilated` on ``backend``, for ``nn.Conv(conv_general_dilated=...)``."""
    return functools.partial(conv_general_dilated, backend=backend)


def learning_loop(obs_shape: tuple[int, ...], backend: str = "xla") -> Callable:
    """The loop for an agent's learning steps on observations of ``obs_shape`` (``lax.scan``'s
    signature): the steps written out (:func:`agentax._xla.scan` with ``python_loop``) for stacked
    frames ``[C, H, W]`` whose convolutions are XLA's (``backend``) on its CPU backend, where a
    convolution inside a loop body runs many times slower (4 Nature-CNN gradient steps of batch 256
    took 51 s in a ``lax.scan``); ``jax.lax.scan`` everywhere else, oneDNN's convolutions included
    (as fast in a scan as written out, and the program compiles in seconds, not minutes).

    The platform is asked when the loop is traced, not here: asking for it creates jax's client,
    and the runner decides first how (:func:`agentax._xla.let_xla_use_every_cpu`)."""
    if len(obs_shape) != 3:
        return lax.scan

    def loop(f, init, xs=None, length=None):
        written_out = jax.default_backend() == "cpu" and backend == "xla"
        return _xla.scan(f, init, xs, length, python_loop=written_out)

    return loop
