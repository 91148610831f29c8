"""Lines that the model cards of single-track and general models share (the collection's
options, the theta box), read from a model's metadata."""

from __future__ import annotations

from agents.potential import model_space
from experiments.potential.collect import ADDED_FIELDS, PACE_SPREADS


def added_options_text(collect: dict) -> str:
    """The ``collect`` options of a model's data that differ from their defaults, as they
    are written on the command line (`` --space extended --start close``...; empty for the
    paper's collection)."""
    return "".join(
        f" --{k} {collect[k]}" for k, v in ADDED_FIELDS.items() if collect.get(k, v) != v
    )


def theta_box_lines(meta: dict) -> list[str]:
    """The model card's line on the theta box the model's features were normalised with (none
    for a model that predates recording it)."""
    if "theta_low" not in meta:
        return []
    space = model_space(meta)
    named = "" if space.name == "paper" else f"; the {space.name} policy space"
    box = ", ".join(f"{lo:g}..{hi:g}" for lo, hi in zip(meta["theta_low"], meta["theta_high"]))
    return [f"* **Theta box** ({', '.join(space.names)}{named}): {box}."]


def pace_text(collect: dict) -> str:
    """How the collection drew the cars' paces, after "every car an MPC with theta uniform in
    its bounds" (empty for the paper's draw over the box)."""
    pace = collect.get("pace", "box")
    if pace == "close":
        return ", zeta close to the race's own, drawn over the box"
    if pace in PACE_SPREADS:
        text = f", zeta within {PACE_SPREADS[pace]:g} of the race's own, drawn over the box"
        return text + (", the slowest car in front" if pace == "overtake" else "")
    return ""
