"""The compiled runner, and the XLA CPU hang it must never meet again (DESIGN.md, "Known hazards")."""

import os
import subprocess
import sys
import textwrap

import pytest

HANG_PROGRAM = textwrap.dedent(
    """
    import os
    import agentax  # pins the process to one CPU before jax starts (agentax._xla.pin_cpu)
    import jax, jax.numpy as jnp, optax
    from agentax.envs import make_jax
    from agentax.nets import PolicyNet, log_prob, sample_action

    env, params, num_envs = make_jax("CartPole-v1"), make_jax("CartPole-v1").default_params(), 8
    net, tx = PolicyNet(2, hidden=(64, 64), activation="tanh"), optax.adam(1e-3)

    def init(key):
        net_key, env_key = jax.random.split(key)
        weights = net.init(net_key, jnp.zeros(4))
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(env_key, num_envs), params)
        return weights, tx.init(weights), state, obs, key

    def update(carry, _):
        weights, opt_state, state, obs, key = carry
        def step(c, _):
            state, obs, key = c
            key, act_key, step_key = jax.random.split(key, 3)
            action = sample_action(act_key, net.apply(weights, obs))
            step_keys = jax.random.split(step_key, num_envs)
            ts, state = jax.vmap(env.step, (0, 0, 0, None))(step_keys, state, action, params)
            return (state, ts.obs, key), (obs, action, ts.reward)
        (state, obs, key), (o, a, r) = jax.lax.scan(step, (state, obs, key), None, 32)
        loss = lambda w: -(log_prob(net.apply(w, o), a) * (r - r.mean())).mean()
        for _ in range(4):
            updates, opt_state = tx.update(jax.grad(loss)(weights), opt_state)
            weights = optax.apply_updates(weights, updates)
        return (weights, opt_state, state, obs, key), r.sum()

    chunk = jax.jit(jax.vmap(lambda carry: jax.lax.scan(update, carry, None, 10)))
    carry = jax.jit(jax.vmap(init))(jax.random.split(jax.random.key(0), 4))
    for call in range(6):
        carry, rewards = chunk(carry)
        jax.block_until_ready(rewards)
    masks = set()
    for task in os.listdir(f"/proc/{os.getpid()}/task"):
        masks.add(tuple(os.sched_getaffinity(int(task))))
    print("calls", call + 1, "affinity", sorted(masks))
    """
)


@pytest.mark.timeout(120)
def test_vmapped_chunk_called_repeatedly_never_hangs():
    """A jitted, vmapped-over-seeds train chunk called 6 times finishes, on one CPU in every thread."""
    env = {k: v for k, v in os.environ.items() if k != "AGENTAX_PIN_CPU"}
    result = subprocess.run(
        [sys.executable, "-c", HANG_PROGRAM], capture_output=True, text=True, timeout=100, env=env
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "calls 6" in result.stdout
    if len(os.sched_getaffinity(0)) > 1:
        masks = result.stdout.split("affinity", 1)[1].strip()
        assert masks.count("(") == 1, f"some thread escaped the one-CPU pin: {masks}"
