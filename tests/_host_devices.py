"""The environment of a child process that forces a count of XLA host devices."""

import os


def host_devices_env(devices: int, **variables) -> dict:
    """os.environ with ``devices`` host devices added to the suite's XLA_FLAGS (tests/conftest.py)
    and ``variables`` set: the child compiles as the suite does."""
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()
    return {**os.environ, "XLA_FLAGS": flags, **variables}
