"""Regenerate ``agents/models/MODEL_CARD.md`` from the metadata inside the shipped models.

    python -m experiments.model_card

Each shipped ``.npz`` carries its training config, data, command and held-out metrics
(written by ``alpha-racer train``); this file only lays them out, so the card cannot drift
from the models.
"""

from __future__ import annotations

from agents.potential import MODEL_DIR, SHIPPED, PotentialModel
from experiments.train import model_card_text
from experiments.train_general import general_model_card_text

HEADER = """# Shipped alpha-potential models

Each model is a value network V and a potential network Phi (see `agents/potential.py`),
trained by `alpha-racer train` on races collected by `alpha-racer collect`: `default`,
`gamma0.98`, `gamma0.995` and `races400` on the `default` track with 3 cars (the paper's
single-track models), `general` on a family of tracks with 2 to 6 cars (any track, 2..8
cars). `agents.potential.load_model(NAME)` loads one. The `alpha` agent's default,
`model="auto"`, races `default` on the track and field it was trained for (`default`, 3
cars) and `general` everywhere else; `model=NAME` picks one. Race data of the same seed are
identical for any worker count, so `alpha-racer collect --races 400` gives exactly the first
400 races of the 4000 (and a family collection's first K races are those of K races).
"""


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
    return "\n".join(parts)


if __name__ == "__main__":
    (MODEL_DIR / "MODEL_CARD.md").write_text(card())
    print(f"wrote {MODEL_DIR / 'MODEL_CARD.md'}")
