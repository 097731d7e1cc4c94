"""The device strategy (so3jax.parallel.devices): a batch split over a mesh gives the values and
the gradients of the whole batch on one device, padding included; programs side by side
run each on its own device; replicated placement; how many devices a batch gets. The
several-device cases run in a child process with 3 forced host devices (the device count
is fixed when JAX starts)."""

import json
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from so3jax.parallel import devices
from tests._host_devices import host_devices_env

THREE_DEVICES = r"""
import json
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from so3jax.parallel import devices

def fn(x, w):
    # a loop whose carry starts from the shared w and becomes per-device (as a rollout's)
    def step(c, _):
        return c * jnp.cos(x) + w[0] * jnp.sin(c + w[1]), None
    c, _ = jax.lax.scan(step, jnp.broadcast_to(w[1], x.shape), None, length=20)
    return {"y": c, "x2": x ** 2}

x = jnp.linspace(0.1, 1.3, 7)  # 7 items over 3 devices: padded to 9
w = jnp.array([0.7, -0.2])
mesh = devices.mesh(jax.devices())
split = jax.jit(devices.split(fn, mesh, batched=(True, False)))
whole, parts = fn(x, w), split(x, w)
cost = lambda f: lambda w: jnp.sum(f(x, w)["y"] ** 2)
grad_whole = jax.grad(cost(fn))(w)
grad_split = jax.jit(jax.grad(cost(devices.split(fn, mesh, batched=(True, False)))))(w)
jac_split = jax.jit(jax.jacfwd(cost(devices.split(fn, mesh, batched=(True, False)))))(w)
seen = devices.side_by_side({name: (lambda: str(jnp.zeros(()).device)) for name in "abcd"})
print(json.dumps({
    "devices": mesh.size,
    "shape": list(parts["y"].shape),
    "values": float(np.max(np.abs(np.asarray(parts["y"]) - np.asarray(whole["y"])))),
    "x2": bool(np.array_equal(parts["x2"], whole["x2"])),
    "grad_whole": np.asarray(grad_whole).tolist(), "grad_split": np.asarray(grad_split).tolist(),
    "jac_split": np.asarray(jac_split).tolist(),
    "seen": seen, "cpus": [str(d) for d in jax.devices("cpu")],
}))
"""


def test_a_batch_split_over_three_devices_has_the_values_and_gradients_of_the_whole():
    env = host_devices_env(3)
    proc = subprocess.run([sys.executable, "-c", THREE_DEVICES], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    assert r["devices"] == 3 and r["shape"] == [7]  # the padding dropped
    assert r["values"] < 1e-14 and r["x2"]
    # the gradient of a shared argument: once, not once per device
    np.testing.assert_allclose(r["grad_split"], r["grad_whole"], rtol=1e-12)
    np.testing.assert_allclose(r["jac_split"], r["grad_whole"], rtol=1e-12)
    cpus = r["cpus"]
    assert r["seen"] == {"a": cpus[0], "b": cpus[1], "c": cpus[2], "d": cpus[0]}


def test_split_over_no_mesh_is_the_function_itself():
    fn = lambda x: x
    assert devices.split(fn, None, batched=(True,)) is fn


def test_placement_is_replicated_with_one_sharding():
    mesh = devices.mesh(jax.devices()[:1])
    placed = devices.place({"a": jnp.ones(3), "b": jnp.zeros(())}, mesh)
    assert {x.sharding for x in jax.tree.leaves(placed)} == {NamedSharding(mesh, PartitionSpec())}
    assert devices.place(placed, None) is placed


def test_a_batch_gets_the_devices_that_each_hold_a_minimum_shard():
    assert devices.devices_for(2, 2, 4) == 1
    assert devices.devices_for(8, 2, 4) == 2
    assert devices.devices_for(8, 16, 4) == 2
    assert devices.devices_for(64, 16, 4) == 16
    assert devices.devices_for(0, 16, 4) == 1
