"""The XLA:CPU settings so3jax adds to XLA_FLAGS: added once, never over the user's."""

from so3jax.parallel import xla_flags as _xla_flags


def test_flags_are_added_once(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    monkeypatch.delenv("SO3JAX_KEEP_XLA_FLAGS", raising=False)
    monkeypatch.setattr(_xla_flags, "_has_avx512", lambda: True)
    _xla_flags.configure_cpu_codegen()
    _xla_flags.configure_cpu_codegen()
    flags = _xla_flags.os.environ["XLA_FLAGS"].split()
    assert flags == ["--xla_dump_to=/tmp/x", _xla_flags.BACKEND_OPTIONS_FLAG, _xla_flags.WIDE_VECTOR_FLAG]


def test_user_settings_win_and_can_opt_out(monkeypatch):
    mine = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=0 --xla_cpu_prefer_vector_width=256"
    monkeypatch.setenv("XLA_FLAGS", mine)
    monkeypatch.setattr(_xla_flags, "_has_avx512", lambda: True)
    _xla_flags.configure_cpu_codegen()
    assert _xla_flags.os.environ["XLA_FLAGS"] == mine
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setenv("SO3JAX_KEEP_XLA_FLAGS", "1")
    _xla_flags.configure_cpu_codegen()
    _xla_flags.use_every_core()
    assert _xla_flags.os.environ["XLA_FLAGS"] == ""


def test_no_wide_vectors_without_avx512(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.delenv("SO3JAX_KEEP_XLA_FLAGS", raising=False)
    monkeypatch.setattr(_xla_flags, "_has_avx512", lambda: False)
    _xla_flags.configure_cpu_codegen()
    assert _xla_flags.os.environ["XLA_FLAGS"] == _xla_flags.BACKEND_OPTIONS_FLAG


def test_collectives_between_host_devices_wait_as_long_as_a_loaded_machine_needs(monkeypatch):
    """With one host device per core, XLA's 40 s limit on a collective's rendezvous is raised;
    where the installed jaxlib knows the flag, a process given it computes (XLA aborts on an
    unknown flag) across two host devices."""
    import subprocess
    import sys

    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.delenv("SO3JAX_KEEP_XLA_FLAGS", raising=False)
    _xla_flags.use_every_core()
    flags = _xla_flags.os.environ["XLA_FLAGS"]
    if not _xla_flags._knows_collective_flags():
        assert "collective" not in flags
        return
    assert "--xla_cpu_collective_call_terminate_timeout_seconds=3600" in flags
    flags = flags.replace(f"device_count={_xla_flags.usable_cores()}", "device_count=2")
    code = ("import jax, jax.numpy as jnp; from jax.sharding import Mesh, NamedSharding, PartitionSpec as P; "
            "x = jax.device_put(jnp.arange(4.0), NamedSharding(Mesh(jax.devices(), ('d',)), P('d'))); "
            "print(len(jax.devices()), float(jnp.sum(x)))")
    out = subprocess.run([sys.executable, "-c", code], env={**_xla_flags.os.environ, "XLA_FLAGS": flags,
                                                           "JAX_PLATFORMS": "cpu"},
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == ["2", "6.0"], out.stderr[-500:]
