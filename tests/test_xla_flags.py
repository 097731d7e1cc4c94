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
