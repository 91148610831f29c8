"""Race metrics that see strategy: passes, wins from behind, time spent close behind.

Winning is not strategy: a faster car wins from any seat. These metrics count what pace alone
does not explain, from nothing but a race's states (every car's Frenet state per step, ``s``
unwrapped, so the order of two cars is the sign of their ``s`` difference, across laps too).

**Pass.** Car i passes car j when it moves from behind j to ahead of j (``s_i - s_j`` changes
sign from negative to positive) *and stays ahead for at least* ``hold_s`` (1 s: 10 control
periods): the order of a pair is *established* by a crossing that holds, and a pass is a change
of the established order, credited to the car that moves ahead. So

* a car that gets ahead and falls back behind within 1 s has not passed (``fell_back``), and
  regaining the place it briefly lost is no pass either (the established order never changed);
* a crossing in the last ``hold_s`` of a race cannot be confirmed and **does not count**
  (``race_end``);
* a crossing with *lateral overlap* (``|n_i - n_j| < contact_dn`` at the crossing, both
  quantities interpolated linearly between the two steps around it) is a pass *through
  contact* (``contact``): the cars' bodies overlap sideways where they are level, so the one
  went through the other rather than around it. It changes the established order, but it is
  counted apart from the clean passes (``pass``) so that it stays visible.

**Win from behind.** The winner (the most progress: the largest final ``s``, exact ties to the
lower car index, as in ``alpha-racer bench``) did not start at the front (the largest ``s`` at
step 0, ties likewise).

**Time within 1 m behind.** Per car, the time [s] of the states after each control period
(steps 1..T) in which some other car is ahead of it by at most ``gap_m`` (1 m):
``0 < s_j - s_i <= gap_m``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: A crossing must hold this long [s] to change the established order (a pass).
PASS_HOLD_S = 1.0
#: "Close behind": another car at most this far ahead along the track [m].
BEHIND_GAP_M = 1.0
#: Kinds of :class:`PassEvent`: a clean pass, a pass through lateral overlap, a crossing that
#: was lost again within ``hold_s``, a crossing in the race's last ``hold_s`` (not counted).
KINDS = ("pass", "contact", "fell_back", "race_end")


@dataclass(frozen=True)
class PassEvent:
    """One crossing against a pair's established order.

    ``step``: the first step (state index) with the passer ahead; ``time_s``: the crossing's
    interpolated time [s] since the start (between ``(step - 1) dt`` and ``step dt``);
    ``passer``, ``passed``: car indices; ``dn_m``: ``|n_passer - n_passed|`` [m] at the
    crossing (interpolated); ``kind``: one of :data:`KINDS`.
    """

    step: int
    time_s: float
    passer: int
    passed: int
    dn_m: float
    kind: str

    def to_dict(self) -> dict:
        d = asdict(self)
        d["time_s"] = round(float(d["time_s"]), 4)
        d["dn_m"] = round(float(d["dn_m"]), 4)
        return d


def _check(states, dt: float, contact_dn: float, hold_s: float) -> np.ndarray:
    states = np.asarray(states, dtype=float)
    if states.ndim != 3 or states.shape[2] < 2 or states.shape[0] < 1:
        raise ValueError(
            f"states must have shape (T + 1, N, 6) (at least s and n per car), got {states.shape}"
        )
    if not np.isfinite(states[:, :, :2]).all():
        raise ValueError("states hold non-finite s or n values; race metrics need finite states")
    for name, v in (("dt", dt), ("contact_dn", contact_dn), ("hold_s", hold_s)):
        if isinstance(v, bool) or not (
            isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v > 0
        ):
            raise ValueError(f"{name} must be a positive number, got {v!r}")
    return states


def hold_steps(dt: float, hold_s: float = PASS_HOLD_S) -> int:
    """Control periods a crossing must hold: ``round(hold_s / dt)`` (10 at dt = 0.1 s), at
    least 1."""
    return max(1, int(round(hold_s / dt)))


def _filled_sign(d: np.ndarray) -> np.ndarray:
    """Sign of ``d`` (T + 1,) with exact zeros (cars level) taking the previous sign, and
    leading zeros the first non-zero one: being level is no change of order. All zeros: +1."""
    sgn = np.sign(d)
    nz = np.flatnonzero(sgn)
    if not nz.size:
        return np.ones_like(sgn)
    idx = np.where(sgn != 0, np.arange(len(sgn)), 0)
    np.maximum.accumulate(idx, out=idx)
    filled = sgn[idx]
    filled[: nz[0]] = sgn[nz[0]]
    return filled


def pass_events(
    states, dt: float = 0.1, contact_dn: float = 0.06, hold_s: float = PASS_HOLD_S
) -> list[PassEvent]:
    """Every crossing against a pair's established order (module docstring), in time order.

    ``states`` (T + 1, N, 6): per step and car the Frenet state ``(s, n, mu, vx, vy, omega)``
    with ``s`` unwrapped [m] (only ``s`` and ``n`` are read); ``dt`` [s] the control period;
    ``contact_dn`` [m] the lateral size of the contact box (``RulesConfig.contact_dn``: one
    car width); ``hold_s`` [s] how long a crossing must hold to count.
    """
    states = _check(states, dt, contact_dn, hold_s)
    T = states.shape[0] - 1
    hold = hold_steps(dt, hold_s)
    s, n = states[:, :, 0], states[:, :, 1]
    events = []
    N = states.shape[1]
    for i in range(N):
        for j in range(i + 1, N):
            d = s[:, i] - s[:, j]
            sgn = _filled_sign(d)
            change = np.flatnonzero(sgn[1:] != sgn[:-1]) + 1  # first step of the new order
            established = sgn[0]
            for c, b in enumerate(change):
                new = sgn[b]
                if new == established:  # the established order restored: no event
                    continue
                # the crossing lies between the last step strictly on the old side and b
                a = b - 1
                while d[a] == 0:
                    a -= 1
                frac = d[a] / (d[a] - d[b])  # in (0, 1]
                dn = abs((1 - frac) * (n[a, i] - n[a, j]) + frac * (n[b, i] - n[b, j]))
                end = change[c + 1] if c + 1 < len(change) else T + 1  # first step lost
                if end - b >= hold:
                    kind = "contact" if dn < contact_dn else "pass"
                    established = new
                elif end <= T:
                    kind = "fell_back"
                else:
                    kind = "race_end"
                passer, passed = (i, j) if new > 0 else (j, i)
                events.append(
                    PassEvent(
                        step=int(b),
                        time_s=float((a + frac * (b - a)) * dt),
                        passer=passer,
                        passed=passed,
                        dn_m=float(dn),
                        kind=kind,
                    )
                )
    events.sort(key=lambda e: (e.time_s, e.passer, e.passed))
    return events


def winner_and_front(states) -> tuple[int, int]:
    """(winner, front car): the car with the largest final ``s`` and the one with the largest
    ``s`` at step 0, exact ties to the lower index (``states`` (T + 1, N, 6))."""
    states = np.asarray(states, dtype=float)
    return int(np.argmax(states[-1, :, 0])), int(np.argmax(states[0, :, 0]))


def behind_time(states, dt: float = 0.1, gap_m: float = BEHIND_GAP_M) -> np.ndarray:
    """(N,) seconds each car spends within ``gap_m`` [m] behind another car: the states after
    steps 1..T in which ``0 < s_j - s_i <= gap_m`` for some j, times ``dt`` [s]."""
    states = _check(states, dt, 1.0, 1.0)
    if not (np.isfinite(gap_m) and gap_m > 0):
        raise ValueError(f"gap_m must be a positive number, got {gap_m!r}")
    s = states[1:, :, 0]  # (T, N)
    ahead = s[:, None, :] - s[:, :, None]  # [t, i, j] = s_j - s_i
    close = ((ahead > 0) & (ahead <= gap_m)).any(axis=2)  # (T, N)
    return close.sum(axis=0) * float(dt)


def interaction_share(states, gap_m: float = BEHIND_GAP_M) -> float:
    """Share of the states after steps 1..T (``states`` (T + 1, N, 6), or a batch
    (R, T + 1, N, 6) of races) in which some car has another within ``gap_m`` [m] behind or
    beside it (``0 <= s_i - s_j <= gap_m`` on unwrapped progress, some i != j): the steps in
    which passing or blocking is possible. A collection's share says how much interaction
    the potential can learn from."""
    st = np.asarray(states, dtype=float)
    if st.ndim == 3:
        st = st[None]
    if st.ndim != 4 or st.shape[-1] != 6 or st.shape[1] < 2 or st.shape[2] < 2:
        raise ValueError(
            f"states must have shape (T + 1, N, 6) or (R, T + 1, N, 6) with "
            f"T >= 1 and N >= 2, got {np.shape(states)}"
        )
    if not (np.isfinite(gap_m) and gap_m > 0):
        raise ValueError(f"gap_m must be a positive number, got {gap_m!r}")
    s = st[:, 1:, :, 0]  # (R, T, N)
    d = np.abs(s[..., :, None] - s[..., None, :])  # (R, T, N, N)
    n = s.shape[-1]
    d[..., np.arange(n), np.arange(n)] = np.inf
    return float((d <= gap_m).any(axis=(-1, -2)).mean())


def race_metrics(
    states,
    dt: float = 0.1,
    contact_dn: float = 0.06,
    hold_s: float = PASS_HOLD_S,
    gap_m: float = BEHIND_GAP_M,
) -> dict:
    """The strategy metrics of one race, as a JSON-ready dict (lists indexed by car):

    * ``passes`` (N,): clean passes credited to each car; ``passes_contact`` (N,): passes
      through lateral overlap; ``fell_back`` (N,): crossings lost again within ``hold_s``;
      ``passes_race_end`` (N,): crossings in the last ``hold_s``, not counted;
    * ``pass_events``: every such crossing (:meth:`PassEvent.to_dict`), in time order;
    * ``winner``, ``front``: car indices (:func:`winner_and_front`); ``won_from_behind``:
      whether they differ;
    * ``behind_1m_s`` (N,): :func:`behind_time` [s].

    Arguments as for :func:`pass_events` and :func:`behind_time`.
    """
    states = _check(states, dt, contact_dn, hold_s)
    N = states.shape[1]
    events = pass_events(states, dt, contact_dn, hold_s)
    count = {k: [0] * N for k in KINDS}
    for e in events:
        count[e.kind][e.passer] += 1
    winner, front = winner_and_front(states)
    return {
        "passes": count["pass"],
        "passes_contact": count["contact"],
        "fell_back": count["fell_back"],
        "passes_race_end": count["race_end"],
        "pass_events": [e.to_dict() for e in events],
        "winner": winner,
        "front": front,
        "won_from_behind": winner != front,
        "behind_1m_s": [round(float(v), 4) for v in behind_time(states, dt, gap_m)],
    }


#: The record fields :func:`race_metrics` adds to a benchmark or league record.
RECORD_KEYS = (
    "passes",
    "passes_contact",
    "fell_back",
    "passes_race_end",
    "pass_events",
    "won_from_behind",
    "behind_1m_s",
)


def record_metrics(states, dt: float = 0.1, contact_dn: float = 0.06) -> dict:
    """The :data:`RECORD_KEYS` of :func:`race_metrics` (a record already names its winner)."""
    m = race_metrics(states, dt, contact_dn)
    return {k: m[k] for k in RECORD_KEYS}


def definition(dt: float = 0.1, contact_dn: float = 0.06) -> dict:
    """The metrics' parameters, for summaries: what a number there means."""
    return {
        "pass_hold_s": PASS_HOLD_S,
        "hold_steps": hold_steps(dt),
        "contact_dn_m": contact_dn,
        "behind_gap_m": BEHIND_GAP_M,
        "dt_s": dt,
    }
