"""Regenerate ``agents/models/MODEL_CARD.md`` from the metadata inside the shipped models.

    python -m experiments.potential.model_card

Each shipped ``.npz`` carries its training config, data, command and held-out metrics
(written by ``alpha-racer train``); this file only lays them out, so the card cannot drift
from the models. A model with measured races (:data:`MEASURED`: committed strategy
benchmarks of ``results/``) gets a section read from their ``strategy.json`` files.
"""

from __future__ import annotations

import json
from pathlib import Path

from agents.potential import MODEL_DIR, SHIPPED, PotentialModel
from experiments.potential.train import model_card_text
from experiments.potential.train_general import general_model_card_text

HEADER = """# Shipped alpha-potential models

Each model is a value network V and a potential network Phi (see `agents/potential.py`),
trained by `alpha-racer train` on races collected by `alpha-racer collect`: `default`,
`gamma0.98`, `gamma0.995` and `races400` on the `default` track with 3 cars (the paper's
single-track models), `general` on a family of tracks with 2 to 6 cars (any track, 2..8
cars), and `extended` on the `default` track with 3 cars in the extended policy space (the
paper's five parameters and `b`, the lap-time line's weight), with its variants of the paper's
kinds, `extended_gamma0.98`, `extended_gamma0.995` and `extended_races400` (the learned
opponents of Table 1 in that space, `alpha-racer bench --paper-table --space extended`), and
`extended_general`, the extended space's track-general model (a family of tracks with 2 to 6
cars, close starts and paces; `alpha:space=extended,model=extended_general`); and
`fullsize_monza`, the full-size class's model (full-size cars with the wake on Monza at full
scale, 3 cars, the extended space; `alpha:model=fullsize_monza`, refused on a 1:43 track),
with its variants of the paper's kinds, `fullsize_monza_gamma0.98`,
`fullsize_monza_gamma0.995` and `fullsize_monza_races400` (the learned opponents of Table 1
in the full-size world, `alpha-racer bench --paper-table --vehicle-class fullsize`), and
`fullsize_monza_wake`, the same class in the wake space (hold the tow, pull out, cover;
races with faster and slower cars, `--pace spread`).
`agents.potential.load_model(NAME)` loads one. The `alpha` agent's default,
`model="auto"`, races `default` on the track and field it was trained for (`default`, 3
cars) and `general` everywhere else; with `space=extended` it races `extended` (which
warns on another track and refuses another field size); `model=NAME` picks one. Race data
of the same seed are identical for any worker count, so `alpha-racer collect --races 400`
gives exactly the first 400 races of the 4000 (and a family collection's first K races are
those of K races).
"""


ROOT = Path(__file__).resolve().parents[2]
#: Shipped models with measured races: name -> (the folder of strategy benchmarks under the
#: repository, one suite with its ``strategy.json`` per sub-folder; the headline bench, the
#: maneuver the model's policy space was built for).
MEASURED = {
    "extended": ("results/strategy_alpha_extended4000", "pass"),
    "extended_general": ("results/strategy_alpha_extended_general", "pass"),
}


def _wins(rows, side: str) -> tuple[int, int]:
    """Total wins and races of ``side`` (``"ego"`` or ``"control"``) over table rows."""
    return sum(r[side]["wins"] for r in rows), sum(r[side]["races"] for r in rows)


def suite_command(config: dict, out: str) -> str:
    """The ``alpha-racer strategy`` command of a suite's stored config writing into ``out``."""
    cmd = (
        f"alpha-racer strategy --ego {config['ego']} --control {config['control']} "
        f"--tracks {' '.join(config['tracks'])} --scenarios {' '.join(config['scenarios'])} "
        f"--races {config['races']} --steps {config['steps']} --seed {config['seed']}"
    )
    if "defend" in config["scenarios"]:
        cmd += f" --zeta-max {config['zeta_max']:g}"
    if "pass" in config["scenarios"] and config.get("pass_opponents", "raceline") != "raceline":
        cmd += f" --pass-opponents {config['pass_opponents']}"
    return f"{cmd} --out {out}"


def measured_text(folder, headline: str) -> str:
    """The card's section on a model's measured strategy benchmarks: per suite folder of
    ``folder`` (``strategy.json``) and bench, the ego's wins beside the control's, summed
    over the tracks, with each suite's command; first a sentence on the ``headline``
    bench. ``FileNotFoundError`` naming the folder when it holds no suite, ``ValueError``
    when no suite has the headline bench."""
    folder = ROOT / folder
    tables = [(p, json.loads(p.read_text())) for p in sorted(folder.glob("*/strategy.json"))]
    if not tables:
        raise FileNotFoundError(f"no strategy benchmark (*/strategy.json) in {folder}")
    rows, commands, head = [], [], None
    for path, t in tables:
        out = str(path.parent.relative_to(ROOT))
        commands.append(f"* `{suite_command(t['config'], out)}`")
        for bench in dict.fromkeys(r["bench"] for r in t["rows"]):
            mine = [r for r in t["rows"] if r["bench"] == bench]
            (ew, n), (cw, _) = _wins(mine, "ego"), _wins(mine, "control")
            c = t["config"]
            opp = c.get("pass_opponents", "raceline") if bench == "pass" else None
            rows.append(
                f"| `{path.parent.name}` | {bench}"
                + (f" (`{opp}`)" if opp and opp != "raceline" else "")
                + f" | {', '.join(r['track'] for r in mine)} | `{c['control']}` "
                f"| {ew}/{n} | {cw}/{n} | {ew - cw:+d} |"
            )
            if bench == headline and head is None:
                head = (ew, cw, n, t["config"])
    if head is None:
        raise ValueError(f"no suite in {folder} has the {headline!r} bench")
    ew, cw, n, c = head
    verdict = "beats" if ew > cw else "does not beat"
    return "\n".join(
        [
            "### Measured: strategy benchmark",
            "",
            f"Ego `{c['ego']}` (this model) against a fixed extended theta (the control) "
            f"in the same seats and races. In `{headline}` against `{c['control']}`, the "
            f"maneuver its policy space "
            f"was built for, the ego wins {ew}/{n} races and the fixed theta {cw}/{n}: the "
            f"model **{verdict}** the fixed extended theta. Wins summed over the tracks:",
            "",
            "| suite | bench | tracks | control | ego wins | control wins | ego - control |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
            "Commands (the ego's model.npz is this file):",
            "",
            *commands,
            "",
        ]
    )


def card() -> str:
    parts = [HEADER]
    for name, file in SHIPPED.items():
        path = MODEL_DIR / file
        if not path.exists():
            parts.append(f"## `{name}`\n\nNot shipped yet (`{file}`).\n")
            continue
        meta = PotentialModel.load(path).meta
        text = general_model_card_text if meta.get("feature_set") == "general" else model_card_text
        body = text(meta).split("\n", 1)[1]
        body = body.replace("\n## ", "\n### ")
        parts.append(f"## `{name}` (`{file}`)\n{body}")
        if name in MEASURED:
            parts.append(measured_text(*MEASURED[name]))
    return "\n".join(parts)


if __name__ == "__main__":
    (MODEL_DIR / "MODEL_CARD.md").write_text(card())
    print(f"wrote {MODEL_DIR / 'MODEL_CARD.md'}")
