"""Lines that the model cards of single-track and general models share (the collection's
options, the theta box), read from a model's metadata."""

from __future__ import annotations

from agents.potential import model_space
from experiments.potential.collect import ADDED_FIELDS, PACE_SPREADS, ZETA_CEILING, CollectConfig


def added_options_text(collect: dict) -> str:
    """The ``collect`` options of a model's data that differ from their defaults, as they
    are written on the command line (`` --space extended --start close``...; empty for the
    paper's collection)."""
    return "".join(
        f" --{k.replace('_', '-')} {collect[k]}"
        for k, v in ADDED_FIELDS.items()
        if collect.get(k, v) != v
    )


def track_steps_text(collect: dict) -> str:
    """The collection's ``--track`` and ``--steps`` where they differ from
    :class:`~experiments.potential.collect.CollectConfig`'s defaults (``default``, 500), as
    written on the command line (empty for the paper's collection)."""
    text = ""
    for name in ("track", "steps"):
        default = getattr(CollectConfig, name)
        if collect.get(name, default) != default:
            text += f" --{name} {collect[name]}"
    return text


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
    its bounds" (empty for the paper's draw over the box); a class's zeta ceiling
    (:data:`~experiments.potential.collect.ZETA_CEILING`) is named after it."""
    pace = collect.get("pace", "box")
    if pace == "close":
        text = ", zeta close to the race's own, drawn over the box"
    elif pace in PACE_SPREADS:
        text = f", zeta within {PACE_SPREADS[pace]:g} of the race's own, drawn over the box"
        text += ", the slowest car in front" if pace == "overtake" else ""
    else:
        text = ""
    vehicle_class = collect.get("vehicle_class", "orca")
    ceiling = ZETA_CEILING.get(vehicle_class)
    if ceiling is not None:
        text += f", zeta at most {ceiling:g} (the {vehicle_class!r} class's ceiling)"
    return text
