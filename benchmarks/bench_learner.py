"""The Atari learners' update with XLA's convolutions and with oneDNN's (``agentax.kernels``), and
torch's on the same CPU.

Rows, all measured in this run:

- one Nature-CNN DQN update of batch 32 (target network forward on ``next_obs``, online forward and
  backward on ``obs``, Adam; ``agentax.agents.dqn.make_learn`` with ``double=False``, no gradient
  clipping), jitted, with each ``AGENTAX_CONV`` backend: ``xla`` (XLA's default float32), ``onednn``
  (float32) and ``onednn-bf16`` (bfloat16 on AMX inside the convolutions and the 3136 → 512 dense
  layer), each on the two CPU clients agentax makes, in a process of its own: jax's client made for
  every CPU (what the host and parallel runners use, so the DQN Atari runs: XLA's thread pool has
  both cores, and runs independent parts of the update, such as the target network's forward pass,
  beside the rest) and made on one CPU (the compiled runner's, the cure for the XLA CPU hang);
- the same update in torch 2.13 (``.bench-venv``, a subprocess): float32 and bf16 autocast, both on
  oneDNN, channels-last, ``torch.set_num_threads`` = the CPUs this process may use;
- ``AGENTAX_CONV=auto``'s choice, measured afresh in this run (``agentax.kernel_choice.resolve``: its own
  process and timing, on the one-CPU client), against the fastest of the rows above;
- one PQN learning iteration of the ``breakout-hour`` preset (Q(λ) targets over a 32 × 64 rollout,
  then 2 epochs × 16 minibatches of 128 through the Nature CNN with LayerNorm, RAdam), per backend,
  its SGD steps written out one after the other in the program (what the runners do on XLA's
  convolutions, which run many times slower inside a ``lax.scan``) and, with oneDNN's, in a
  ``lax.scan`` (what the runners do there: ``agentax.kernels.learning_loop``), with the seconds of
  the first call (compiling).

Each figure is the fastest of several repeats of a timed loop (the machine is shared: the fastest is
the least disturbed). GFLOP/s counts the multiply-adds of the convolutions and dense layers twice:
a forward pass of one frame stack is 18.7 MFLOP; a DQN update is 3 forward passes' worth per sample
(target forward, online forward, the backward's two products per layer) less the first
convolution's input gradient, which is never computed.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BENCH_VENV = ROOT / ".bench-venv"
BATCH = 32
REPEATS = 5
LOOP = 10
BACKENDS = ("xla", "onednn", "onednn-bf16")
LAYERS = ((4, 32, 8, 4, 84), (32, 64, 4, 2, 20), (64, 64, 3, 1, 9))  # in, out, size, stride, input side


def layer_flops() -> list[float]:
    """FLOPs of one frame stack through each conv layer and the dense 512 (2 per multiply-add)."""
    flops = []
    for c, o, k, s, side in LAYERS:
        out = (side - k) // s + 1
        flops.append(2.0 * out * out * o * k * k * c)
    flops.append(2.0 * 3136 * 512)
    return flops


def dqn_update_flops(batch: int = BATCH) -> float:
    """Target forward + online forward + backward (two products per layer, no input gradient for
    the first convolution) for ``batch`` samples."""
    per_layer = layer_flops()
    forward = sum(per_layer)
    return batch * (2 * forward + 2 * forward - per_layer[0])


TORCH_SCRIPT = r"""
import json, sys, time
import torch, torch.nn as nn
threads, batch, repeats, loop = map(int, sys.argv[1:5])
torch.set_num_threads(threads)
def net():
    return nn.Sequential(
        nn.Conv2d(4, 32, 8, 4), nn.ReLU(), nn.Conv2d(32, 64, 4, 2), nn.ReLU(), nn.Conv2d(64, 64, 3, 1),
        nn.ReLU(), nn.Flatten(), nn.Linear(3136, 512), nn.ReLU(), nn.Linear(512, 4),
    ).to(memory_format=torch.channels_last)
online, target = net(), net()
target.load_state_dict(online.state_dict())
opt = torch.optim.Adam(online.parameters(), lr=1e-4)
obs = torch.randint(0, 256, (batch, 4, 84, 84), dtype=torch.uint8)
next_obs = torch.randint(0, 256, (batch, 4, 84, 84), dtype=torch.uint8)
action = torch.zeros(batch, dtype=torch.long)
reward = torch.ones(batch)
def prep(x):
    return (x.float() / 255.0).contiguous(memory_format=torch.channels_last)
def update(bf16):
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        with torch.no_grad():
            q_next = target(prep(next_obs)).float().max(1).values
        q = online(prep(obs)).float().gather(1, action[:, None])[:, 0]
        loss = nn.functional.smooth_l1_loss(q, reward + 0.99 * q_next)
    opt.zero_grad()
    loss.backward()
    opt.step()
out = {}
for bf16 in (False, True):
    for _ in range(3):
        update(bf16)
    best = 1e9
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(loop):
            update(bf16)
        best = min(best, (time.perf_counter() - start) / loop)
    out["bf16" if bf16 else "f32"] = best * 1e3
print(json.dumps({"torch": torch.__version__, **out}))
"""


def torch_times() -> tuple[dict | None, str]:
    """torch's DQN update in ms (f32 and bf16 autocast) from ``.bench-venv``, or None and why not."""
    python = BENCH_VENV / "bin" / "python"
    if not python.exists():
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from bench_atari import bench_venv_python

        found, why = bench_venv_python()
        if found is None:
            return None, why
    threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    args = [str(python), "-c", TORCH_SCRIPT, str(threads), str(BATCH), str(REPEATS), str(LOOP)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        return None, done.stderr.strip()[-300:]
    return json.loads(done.stdout.strip().splitlines()[-1]), ""


def fastest(fn, args, repeats: int = REPEATS, loop: int = LOOP, carry: bool = True) -> float:
    """The fastest of ``repeats`` timed loops of ``loop`` calls, in ms per call (the state carried)."""
    import jax

    state, rest = args[0], args[1:]
    jax.block_until_ready(fn(state, *rest))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(loop):
            out = fn(state, *rest)
            if carry:
                state = out[0]
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - start) / loop)
    return best * 1e3


def traced_per_backend(make, backends=BACKENDS) -> dict:
    """``{backend: (jitted fn, args, seconds of its first call)}``, each built by ``make(backend)``
    on that convolution backend, traced and compiled."""
    import jax

    from agentax import kernels

    fns = {}
    for backend in backends:
        if backend != "xla" and not kernels.available():
            continue
        fn, args = make(backend)
        fn = jax.jit(fn)
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))  # trace and compile now
        fns[backend] = (fn, args, time.perf_counter() - start)
    return fns


def dqn_case(backend: str):
    import jax
    import jax.numpy as jnp

    from agentax.agents import dqn
    from agentax.replay.core import ReplaySample, Transition

    cfg = dqn.DQNConfig(double=False, batch_size=BATCH, max_grad_norm=None, learning_rate=1e-4)
    rng = np.random.default_rng(0)
    frames = [jnp.asarray(rng.integers(0, 256, (BATCH, 4, 84, 84), dtype=np.uint8)) for _ in range(2)]
    transition = Transition(
        obs=frames[0],
        action=jnp.asarray(rng.integers(0, 4, BATCH), jnp.int32),
        reward=jnp.ones(BATCH),
        next_obs=frames[1],
        terminated=jnp.zeros(BATCH, bool),
        truncated=jnp.zeros(BATCH, bool),
        num_steps=jnp.ones(BATCH, jnp.int32),
    )
    sample = ReplaySample(transition, jnp.zeros(BATCH, jnp.int32), jnp.ones(BATCH))
    state = dqn.init(jax.random.key(0), frames[0][0], 4, cfg, backend)
    return dqn.make_learn(cfg), (state, sample)


def pqn_case(written_out: bool, backend: str):
    """PQN's learning iteration on ``backend``'s convolutions, its SGD steps written out one after
    the other in the program or in a ``jax.lax.scan``."""
    import jax
    import jax.numpy as jnp

    from agentax import _xla
    from agentax.agents import pqn
    from agentax.agents.presets import PQN_PRESETS
    from agentax.agents.protocol import EnvSpec
    from agentax.envs.core import Discrete
    from agentax.replay.core import Transition

    cfg = PQN_PRESETS["breakout-hour"].config
    spec = EnvSpec((4, 84, 84), Discrete(4), jnp.uint8)
    net = pqn.q_network(cfg, spec, backend)
    steps, envs = cfg.num_steps, cfg.num_envs
    rng = np.random.default_rng(0)
    frames = [jnp.asarray(rng.integers(0, 256, (steps, envs, 4, 84, 84), dtype=np.uint8)) for _ in range(2)]
    rollout = Transition(
        obs=frames[0],
        action=jnp.asarray(rng.integers(0, 4, (steps, envs)), jnp.int32),
        reward=jnp.asarray(rng.random((steps, envs)), jnp.float32),
        next_obs=frames[1],
        terminated=jnp.zeros((steps, envs), bool),
        truncated=jnp.zeros((steps, envs), bool),
        num_steps=jnp.ones((steps, envs), jnp.int32),
        info={"epsilon": jnp.zeros((steps, envs))},
    )
    params = net.init(jax.random.key(0), frames[0][0, :1])
    state = pqn.PQNState(params, pqn.optimizer(cfg).init(params), jnp.int32(0))
    q_values = pqn.q_values_of(net, spec)

    loop = functools.partial(_xla.scan, python_loop=written_out)

    def learn(state, rollout, key):
        return pqn.learn(state, rollout, key, q_values, cfg, loop)

    return learn, (state, rollout, jax.random.key(1))


CLIENTS = {"every-cpu": "XLA on every CPU (host, parallel)", "one-cpu": "XLA on one CPU (compiled)"}


def dqn_update_ms(backend: str) -> float:
    """The DQN update with ``backend``'s convolutions in this process, in ms."""
    fn, args, _ = traced_per_backend(dqn_case, (backend,))[backend]
    return fastest(fn, args, repeats=3 * REPEATS)


def dqn_update_ms_on(client: str) -> dict:
    """``{backend: ms}``: :func:`dqn_update_ms` for each backend in a process of its own whose jax CPU
    client is ``client``'s, as a training process runs one backend (a process that had run the other
    backends' programs first ran oneDNN bf16's 10-25 % slower here)."""
    from agentax import kernels

    times = {}
    for backend in BACKENDS if kernels.available() else ("xla",):
        done = subprocess.run(
            [sys.executable, __file__, "--dqn", client, backend],
            capture_output=True,
            text=True,
            check=True,
            timeout=600,
        )
        times[backend] = float(done.stdout.strip().splitlines()[-1])
    return times


def auto_against_fastest(auto: dict, dqn_ms: dict) -> str:
    """Whether ``AGENTAX_CONV=auto``'s choice, measured afresh in this run, is the fastest backend
    of this run's DQN updates on each client."""
    fastest = {client: min(times, key=times.get) for client, times in dqn_ms.items()}
    same = all(backend == auto["backend"] for backend in fastest.values())
    measured = ", ".join(f"{name} {ms:.1f} ms" for name, ms in auto["ms"].items()) or "unmeasured"
    return (
        f"AGENTAX_CONV=auto chose {auto['backend']} on {auto['cpu']} ({auto['why']}: {measured}); "
        f"the fastest here: {', '.join(f'{b} ({c})' for c, b in fastest.items())}: "
        + ("the same." if same else "NOT the same.")
    )


def run() -> dict:
    from agentax import kernel_choice, kernels

    flops = dqn_update_flops()
    dqn_ms = {client: dqn_update_ms_on(client) for client in CLIENTS}
    auto = kernel_choice.resolve(*kernel_choice.candidates(), path=kernel_choice.cache_path(), again=True)
    torch, torch_why = torch_times()
    pqn = {}  # (loop, backend) → (ms, compile s); XLA's convolutions are too slow in a scan to time
    for loop, written_out, backends in (
        ("written out", True, ("xla", "onednn-bf16")),
        ("lax.scan", False, ("onednn-bf16",)),
    ):
        fns = traced_per_backend(functools.partial(pqn_case, written_out), backends)
        for backend, (fn, args, first) in fns.items():
            pqn[loop, backend] = (fastest(fn, args, repeats=2, loop=1), first)

    rows = []
    labels = {
        "xla": "agentax, XLA f32",
        "onednn": "agentax, oneDNN f32",
        "onednn-bf16": "agentax, oneDNN bf16",
    }
    for client, times in dqn_ms.items():
        for backend, ms in times.items():
            label = f"{labels[backend]}, {CLIENTS[client]}"
            rows.append(["DQN update, batch 32", label, round(ms, 2), round(flops / ms / 1e6, 1), None])
    if auto["ms"]:
        ms = auto["ms"][auto["backend"]]
        label = f"AGENTAX_CONV=auto's choice: {labels[auto['backend']]}, its own measure (one-cpu)"
        rows.append(["DQN update, batch 32", label, round(ms, 2), round(flops / ms / 1e6, 1), None])
    if torch is not None:
        for kind, label in (("f32", "torch f32"), ("bf16", "torch bf16 autocast")):
            gflops = round(flops / torch[kind] / 1e6, 1)
            rows.append(["DQN update, batch 32", label, round(torch[kind], 2), gflops, None])
    for (loop, backend), (ms, first) in pqn.items():
        label = f"{labels[backend]}, {loop}"
        rows.append(["PQN breakout-hour iteration", label, round(ms, 1), None, round(first, 1)])
    impls = {
        f"conv{i + 1}": kernels.implementation("fwd", (BATCH, side, side, c), (k, o, s), bf16=True)
        for i, (c, o, k, s, side) in enumerate(LAYERS)
    }
    impls["dense"] = kernels.implementation("matmul", (BATCH, 3136), (512,), bf16=True)
    ratios = [
        f"oneDNN {b.removeprefix('onednn-') if '-' in b else 'f32'} {times['xla'] / ms:.2f}× ({client})"
        for client, times in dqn_ms.items()
        for b, ms in times.items()
        if b != "xla"
    ]
    loaded = "loaded" if kernels.available() else f"unavailable: {kernels.unavailable_reason()}"
    unrolled = {backend: ms for (loop, backend), (ms, _) in pqn.items() if loop == "written out"}
    pqn_ratio = (
        f"; PQN iteration bf16 {unrolled['xla'] / unrolled['onednn-bf16']:.2f}×"
        if "onednn-bf16" in unrolled
        else ""
    )
    notes = (
        f"{__doc__.strip()}\n\nRatios to XLA's DQN update in this run: {', '.join(ratios)}{pqn_ratio}. "
        f"{auto_against_fastest(auto, dqn_ms)} "
        f"oneDNN {loaded}; bf16 forward implementations: {impls}. "
        + (f"torch {torch['torch']}." if torch else f"torch not measured: {torch_why}")
    )
    return {
        "name": "learner",
        "title": "Atari learner update: XLA's and oneDNN's convolutions, and torch's",
        "headers": ["update", "implementation", "ms per update", "GFLOP/s", "compile s"],
        "rows": rows,
        "notes": notes,
    }


if __name__ == "__main__":
    if sys.argv[1:2] == ["--dqn"]:
        from agentax import _xla

        if sys.argv[2] == "every-cpu":
            _xla.let_xla_use_every_cpu()
        print(dqn_update_ms(sys.argv[3]))
        sys.exit()
    result = run()
    print(json.dumps(result, indent=1))
