"""Line styles of the controllers in every figure: matplotlib keyword arguments (line
style, color, label) by the controller's registry name.

A controller without a style of its own is drawn with matplotlib's next color, labelled
with its registry label (its name where it is not registered); :func:`register` gives
it one.
"""

from __future__ import annotations

from so3jax.controllers import registry

STYLES: dict[str, dict] = {
    "pd": {"ls": "--", "color": "tab:red", "label": "PD"},
    "adaptive": {"ls": "-", "color": "tab:blue", "label": "adaptive"},
    "open_loop": {"ls": ":", "color": "tab:gray", "label": "open loop"},
    "mrp_feedback": {"ls": "-", "color": "tab:purple", "label": "MRP feedback"},
    "sliding_mode": {"ls": "-.", "color": "tab:green", "label": "sliding mode"},
}


def default(name: str) -> dict:
    """The style of a controller without one: its label only."""
    try:
        return {"label": registry.get(name).label}
    except ValueError:
        return {"label": name}


def register(name: str, **style) -> dict:
    """Set the style of controller ``name`` (e.g. ``color="tab:olive", label="my law"``);
    the label defaults to :func:`default`'s. Returns the style."""
    STYLES[name] = {**default(name), **style}
    return dict(STYLES[name])


def style(name: str) -> dict:
    """Matplotlib keyword arguments (line style, color, label) of a controller (a copy)."""
    return dict(STYLES[name]) if name in STYLES else default(name)
