"""Real circuits: the shipped TUMFTM files, their lookup, full scale, the download, and the
race settings scaled to the car's size. No network: downloads read local archives."""

from __future__ import annotations

import hashlib
import io
import os
import tarfile
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from racing_env import tracks
from racing_env.circuits import SHIPPED, shipped_dir
from racing_env.circuits import download as dl
from racing_env.config import RaceConfig, RulesConfig, StartConfig
from racing_env.raceline import RacelineConfig
from racing_env.scaling import (
    REFERENCE_SIZE,
    SCALED_FIELDS,
    scaled_configs,
    size_ratios,
    vehicle_size,
)
from racing_env.tracks import (
    RANDOM_TRACKS,
    make_track,
    random_track,
    track_names,
    track_scale,
    tumftm_dir,
    tumftm_dirs,
    tumftm_file,
)
from racing_env.vehicle import VehicleParams

SHARED = next(
    (
        p / "shared" / "tracks" / "tumftm"
        for p in Path(tracks.__file__).resolve().parents[:4]
        if (p / "shared" / "tracks" / "tumftm").is_dir()
    ),
    None,
)
needs_shared = pytest.mark.skipif(SHARED is None, reason="repository copy of the database absent")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def fresh_cache(monkeypatch):
    """make_track's memo emptied for the test (and restored afterwards)."""
    monkeypatch.setattr(tracks, "_CACHE", {})


@pytest.fixture
def no_database(monkeypatch, fresh_cache):
    """As for a pip user: no ALPHA_RACER_TUMFTM, no repository copy, nothing downloaded."""
    monkeypatch.delenv("ALPHA_RACER_TUMFTM", raising=False)
    monkeypatch.setattr(tracks, "_database_dirs", lambda: [])


# ------------------------------------------------------------------ shipped circuits
def test_shipped_files_attribution_and_licence():
    d = shipped_dir()
    assert sorted(p.stem for p in d.glob("*.csv")) == sorted(SHIPPED)
    for name in SHIPPED:
        assert _sha(d / f"{name}.csv") == dl.TRACK_SHA256[name], name
    licence = (d / "LICENSE").read_text()
    assert "GNU LESSER GENERAL PUBLIC LICENSE" in licence and "Version 3" in licence
    readme = (d / "README.md").read_text()
    assert "TUMFTM/racetrack-database" in readme and dl.PINNED_COMMIT in readme
    assert "unmodified" in readme and "Lesser General Public License" in readme


@needs_shared
def test_shipped_files_byte_identical_to_repository_copy():
    for name in SHIPPED:
        assert (shipped_dir() / f"{name}.csv").read_bytes() == (SHARED / f"{name}.csv").read_bytes()
    assert (shipped_dir() / "LICENSE").read_bytes() == (SHARED / "LICENSE").read_bytes()


@needs_shared
def test_checksum_table_matches_repository_copy():
    assert {p.stem: _sha(p) for p in SHARED.glob("*.csv")} == dl.TRACK_SHA256


@needs_shared
def test_shipped_circuits_load_without_database(no_database):
    assert tumftm_dir() is None and tumftm_dirs() == [shipped_dir()]
    assert track_names() == ["default", "oval"] + [f"tumftm:{n}" for n in sorted(SHIPPED)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        shipped = {n: make_track(f"tumftm:{n}") for n in SHIPPED}
        tracks._CACHE.clear()
        repo = {n: tracks.load_tumftm_csv(SHARED / f"{n}.csv", scale=1 / 43) for n in SHIPPED}
    for n in SHIPPED:  # the same track, wherever the file was found
        assert shipped[n].fingerprint() == repo[n].fingerprint()
        assert shipped[n].name == n
    with pytest.raises(ValueError, match="circuits download"):
        make_track("tumftm:Suzuka")


def test_lookup_order_per_name(monkeypatch, tmp_path, fresh_cache):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "Monza.csv").write_bytes((shipped_dir() / "Spa.csv").read_bytes())
    monkeypatch.setenv("ALPHA_RACER_TUMFTM", str(mine))
    assert tumftm_dirs()[0] == mine and tumftm_dirs()[-1] == shipped_dir()
    assert tumftm_file("Monza") == mine / "Monza.csv"  # the variable's folder first
    assert tumftm_file("Spa") is not None and tumftm_file("Spa").parent != mine  # falls through
    assert tumftm_file("../Monza") is None and tumftm_file("") is None


def test_download_folder_is_looked_up(monkeypatch, tmp_path, fresh_cache):
    monkeypatch.delenv("ALPHA_RACER_TUMFTM", raising=False)
    cache = tmp_path / "cache"
    (cache / "tumftm").mkdir(parents=True)
    (cache / "tumftm" / "Extra.csv").write_bytes((shipped_dir() / "Spa.csv").read_bytes())
    monkeypatch.setattr(dl, "default_dest", lambda: cache / "tumftm")
    dirs = tumftm_dirs()
    assert cache / "tumftm" in dirs and dirs[-1] == shipped_dir()
    if SHARED is not None:  # the repository copy comes first
        assert dirs.index(SHARED) < dirs.index(cache / "tumftm")
    assert tumftm_file("Extra") == cache / "tumftm" / "Extra.csv"
    assert "tumftm:Extra" in track_names()


# ------------------------------------------------------------------ scale per class
def test_track_scale_and_default_unchanged(fresh_cache):
    assert track_scale("orca") == 1 / 43 and track_scale() == 1 / 43
    assert track_scale("fullsize") == 1.0
    with pytest.raises(ValueError, match="unknown vehicle class"):
        track_scale("kart")
    with pytest.raises(ValueError, match="unknown vehicle class"):
        make_track("random:1", vehicle_class="kart")
    with pytest.raises(ValueError, match="sized for the 'orca' class"):
        make_track("default", vehicle_class="fullsize")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = make_track("tumftm:Monza")
        b = make_track("tumftm:Monza", vehicle_class="orca")
        c = tracks.load_tumftm_csv(tumftm_file("Monza"), scale=1 / 43)
    assert a is b and a.fingerprint() == c.fingerprint()
    assert make_track("random:5").fingerprint() == random_track(5).fingerprint()
    assert make_track("random:5", vehicle_class="orca") is make_track("random:5")


def test_monza_at_full_scale(fresh_cache):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = make_track("tumftm:Monza", vehicle_class="fullsize")
        same = make_track("tumftm:Monza", scale=1.0)
        small = make_track("tumftm:Monza")
    # the same geometry, but the class travels with the track: the fingerprints differ
    assert np.array_equal(full.x, same.x) and np.array_equal(full.w_left, same.w_left)
    assert (full.vehicle_class, same.vehicle_class) == ("fullsize", "orca")
    assert full.fingerprint() != same.fingerprint()
    assert full.length == pytest.approx(5793, rel=0.005)  # the real lap: 5.793 km
    assert full.length == pytest.approx(43 * small.length, rel=1e-6)
    width = full.w_left + full.w_right
    assert 9.0 < float(np.mean(width)) < 12.0 and float(np.min(width)) > 7.0
    assert float(np.max(width)) < 20.0


def test_procedural_full_size_tracks(fresh_cache):
    cfg = RANDOM_TRACKS["fullsize"]
    assert 3000 <= cfg.length <= 6000 and 10 <= 2 * cfg.half_width <= 15
    for seed in (0, 1, 2):
        t = make_track(f"random:{seed}", vehicle_class="fullsize")
        assert t.length == pytest.approx(cfg.length, rel=0.01)
        assert np.allclose(t.w_left + t.w_right, 2 * cfg.half_width)
        radius = 1 / np.max(np.abs(t.kappa))
        assert 1.5 * cfg.half_width < radius < 150.0  # real corners, not a 4.5 km blob
        assert t.fingerprint() != make_track(f"random:{seed}").fingerprint()
    orca = RANDOM_TRACKS["orca"]
    assert (orca.length, orca.half_width, orca.control_range) == (30.0, 0.25, (8, 14))
    with pytest.raises(ValueError, match="control_range"):
        random_track(1, control_range=(5, 5))


# ------------------------------------------------------------------ download
def _archive(path: Path, files: dict[str, bytes], commit: str = dl.PINNED_COMMIT) -> Path:
    """A GitHub-style archive: racetrack-database-<commit>/tracks/*.csv, LICENSE, extras."""
    top = f"racetrack-database-{commit}"
    with tarfile.open(path, "w:gz") as tar:
        entries = {f"{top}/tracks/{n}.csv": b for n, b in files.items()}
        entries[f"{top}/LICENSE"] = b"LGPL-3.0 text\n"
        entries[f"{top}/README.md"] = b"readme\n"
        entries[f"{top}/racelines/Monza.csv"] = b"not a track\n"
        for name, data in entries.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


def _fake(tmp_path, n=3):
    files = {f"T{i}": f"# x_m,y_m,w_tr_right_m,w_tr_left_m\n{i},0,1,1\n".encode() for i in range(n)}
    sums = {k: hashlib.sha256(v).hexdigest() for k, v in files.items()}
    return files, sums


def _opener(archive: Path, calls: list):
    def open_(url):
        calls.append(url)
        return open(archive, "rb")

    return open_


def test_download_verifies_and_stores(tmp_path):
    files, sums = _fake(tmp_path)
    archive = _archive(tmp_path / "a.tar.gz", files)
    calls: list = []
    dest = tmp_path / "cache" / "tumftm"
    got = dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, calls))
    assert got == dest and calls == [dl.archive_url()]
    assert sorted(p.name for p in dest.iterdir()) == [
        "LICENSE",
        "README.md",
        "SOURCE.json",
        "T0.csv",
        "T1.csv",
        "T2.csv",
    ]
    assert (dest / "T1.csv").read_bytes() == files["T1"]
    # present and complete: no second download, unless forced
    dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, calls))
    assert len(calls) == 1
    dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, calls), force=True)
    assert len(calls) == 2 and (dest / "T2.csv").read_bytes() == files["T2"]
    assert [p.name for p in dest.parent.iterdir()] == ["tumftm"]  # nothing left beside it


def test_download_checksum_mismatch_names_file_and_hashes(tmp_path):
    files, sums = _fake(tmp_path)
    bad = dict(files, T1=b"# x_m,y_m,w_tr_right_m,w_tr_left_m\n9,9,9,9\n")
    archive = _archive(tmp_path / "a.tar.gz", bad)
    dest = tmp_path / "cache" / "tumftm"
    with pytest.raises(dl.ChecksumError) as err:
        dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, []))
    msg = str(err.value)
    assert "T1.csv" in msg and sums["T1"] in msg and hashlib.sha256(bad["T1"]).hexdigest() in msg
    assert not dest.exists() and list(dest.parent.iterdir()) == []
    # a missing file and an unexpected one are errors too
    archive = _archive(tmp_path / "b.tar.gz", {k: files[k] for k in ("T0", "T1")})
    with pytest.raises(dl.ChecksumError, match="missing.*T2.csv"):
        dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, []))
    archive = _archive(tmp_path / "c.tar.gz", dict(files, Extra=b"x\n"))
    with pytest.raises(dl.ChecksumError, match="not in the checksum table: Extra.csv"):
        dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, []))
    (tmp_path / "junk").write_bytes(b"<html>not found</html>")
    with pytest.raises(ValueError, match="not a tar archive"):
        dl.download_racetrack_database(dest, checksums=sums, opener=_opener(tmp_path / "junk", []))
    assert list(dest.parent.iterdir()) == []
    with pytest.raises(ValueError, match="no checksum table"):
        dl.download_racetrack_database(dest, commit="0" * 40)


def test_interrupted_download_leaves_previous_folder(tmp_path):
    files, sums = _fake(tmp_path)
    archive = _archive(tmp_path / "a.tar.gz", files)
    dest = tmp_path / "cache" / "tumftm"
    dl.download_racetrack_database(dest, checksums=sums, opener=_opener(archive, []))
    before = {p.name: p.read_bytes() for p in dest.iterdir()}

    class Dying(io.BytesIO):
        def read(self, n=-1):
            if self.tell() > 10:
                raise KeyboardInterrupt  # the process is stopped mid-download
            return super().read(min(n, 8))

    with pytest.raises(KeyboardInterrupt):
        dl.download_racetrack_database(
            dest, checksums=sums, force=True, opener=lambda url: Dying(archive.read_bytes())
        )
    assert {p.name: p.read_bytes() for p in dest.iterdir()} == before
    assert [p.name for p in dest.parent.iterdir()] == ["tumftm"]
    # a partial folder left by a killed process is removed once it is an hour old
    stale = dest.parent / ".tumftm.partial-old"
    (stale / "tumftm").mkdir(parents=True)
    fresh = dest.parent / ".tumftm.partial-new"
    fresh.mkdir()
    old = time.time() - 2 * dl.STALE_SECONDS
    os.utime(stale, (old, old))
    dl.download_racetrack_database(dest, checksums=sums, force=True, opener=_opener(archive, []))
    assert not stale.exists() and fresh.exists()


@needs_shared
def test_download_main_with_pinned_table(tmp_path, capsys):
    """The command line, on an archive of the repository copy (file:// URL): the pinned
    table accepts it; the folder then serves every circuit."""
    files = {p.stem: p.read_bytes() for p in SHARED.glob("*.csv")}
    archive = _archive(tmp_path / "db.tar.gz", files)
    dest = tmp_path / "db"
    assert dl.main(["--dest", str(dest), "--url", archive.as_uri(), "--quiet"]) == 0
    assert "25 circuits" in capsys.readouterr().out
    assert {p.stem for p in dest.glob("*.csv")} == set(dl.TRACK_SHA256)
    files["Monza"] = files["Monza"].replace(b"5.720,5.869", b"5.720,5.870")
    bad = _archive(tmp_path / "bad.tar.gz", files)
    args = ["--dest", str(tmp_path / "db2"), "--url", bad.as_uri(), "--quiet"]
    assert dl.main(args) == 1
    err = capsys.readouterr().err
    assert "checksum mismatch for tracks/Monza.csv" in err and dl.TRACK_SHA256["Monza"] in err
    assert not (tmp_path / "db2").exists()


# ------------------------------------------------------------------ scaled settings
def test_scaled_configs_orca_is_the_defaults():
    for vehicle in ("orca", VehicleParams(), REFERENCE_SIZE):
        s = scaled_configs(vehicle)
        assert (s.k_len, s.k_wid) == (1.0, 1.0)
        assert s.rules == RulesConfig() and s.start == StartConfig()
        assert s.preview_ds == RaceConfig().preview_ds and s.raceline == RacelineConfig()
        assert s.race_config() == RaceConfig()
    assert scaled_configs("orca").follower == {
        "preview_min": 0.5,
        "yield_gap": 0.0,
        "yield_behind": 0.2,
        "yield_ahead": 0.4,
    }


def test_scaled_configs_scale_by_length_or_width():
    k = 39.0
    s = scaled_configs((0.12 * k, 0.06 * 2))  # 39x longer, twice as wide
    assert s.k_len == pytest.approx(k) and s.k_wid == pytest.approx(2.0)
    r, st = RulesConfig(), StartConfig()
    assert s.rules.contact_ds == pytest.approx(k * r.contact_ds)
    assert s.rules.contact_dn == pytest.approx(2 * r.contact_dn)
    assert s.rules.wall_margin == pytest.approx(2 * r.wall_margin)
    for name in ("s0", "grid_gap", "region_length", "region_gap", "min_gap"):
        assert getattr(s.start, name) == pytest.approx(k * getattr(st, name)), name
    assert s.preview_ds == pytest.approx(k * RaceConfig().preview_ds)
    assert s.raceline.margin == pytest.approx(2 * RacelineConfig().margin)
    assert s.raceline.point_spacing == pytest.approx(k * RacelineConfig().point_spacing)
    assert s.follower["yield_ahead"] == pytest.approx(k * 0.4)
    # what is not a length stays as it is
    for name in ("front_factor", "rear_factor", "offtrack_factor", "max_substeps"):
        assert getattr(s.rules, name) == getattr(r, name)
    assert (s.start.lateral_jitter, s.start.speed, s.start.mode) == (0.8, 0.0, "regions")
    race = s.race_config(n_cars=2)
    assert race.n_cars == 2 and race.start == s.start and race.n_preview == 10
    # given settings are scaled, not the defaults
    custom = scaled_configs((0.24, 0.06), start=StartConfig(region_length=1.0))
    assert custom.start.region_length == pytest.approx(2.0)
    # every scaled field exists
    for cls in (RulesConfig, StartConfig, RaceConfig, RacelineConfig):
        assert set(SCALED_FIELDS[cls.__name__]) <= set(cls.__dataclass_fields__)


def test_full_size_class_sizes():
    assert vehicle_size("fullsize") == (4.7, 2.0)
    k_len, k_wid = size_ratios("fullsize")
    assert k_len == pytest.approx(4.7 / 0.12) and k_wid == pytest.approx(2.0 / 0.06)
    s = scaled_configs("fullsize")
    assert s.rules.contact_ds == pytest.approx(4.7) and s.rules.contact_dn == pytest.approx(2.0)
    # three start regions fit easily on a full-size circuit
    span = 3 * s.start.region_length + 2 * s.start.region_gap
    assert span < 0.05 * RANDOM_TRACKS["fullsize"].length
    for bad in ("kart", (1.0,), (0.0, 1.0), (1.0, float("nan")), object()):
        with pytest.raises(ValueError):
            vehicle_size(bad)


def test_full_size_race_starts_in_scaled_regions():
    from racing_env.core import start_states

    s = scaled_configs("fullsize")
    track = make_track("random:0", vehicle_class="fullsize")
    x = start_states(track, 3, s.start, 2.0, np.random.default_rng(0), order=[0, 1, 2])
    step = s.start.region_length + s.start.region_gap
    for i in range(3):
        front = s.start.s0 - i * step
        assert front - s.start.region_length <= x[i, 0] <= front
    assert np.all(np.abs(x[:, 1]) <= 6.0 - 1.0)


def test_the_command_line_lists_and_downloads(tmp_path, capsys):
    """``alpha-racer circuits list`` names each circuit's file; ``circuits download`` from an
    unreachable archive fails with exit status 1 and a message naming the URL."""
    from experiments.cli import main

    assert main(["circuits", "list"]) == 0
    out = capsys.readouterr().out
    monza = next(line for line in out.splitlines() if line.startswith("tumftm:Monza "))
    assert monza.split()[-1].endswith("Monza.csv")
    url = (tmp_path / "missing.tar.gz").as_uri()
    rc = main(["circuits", "download", "--quiet", "--url", url, "--dest", str(tmp_path / "db")])
    assert rc == 1
    err = capsys.readouterr().err
    assert err.startswith("alpha-racer circuits download: error: cannot download " + url)
    assert not (tmp_path / "db").exists()  # nothing half-written
