"""Policy files that must not load, and answers that must not pass: non-finite or malformed
weights and normalizers, ``meta`` outside its schema, truncated and oversized files, zip bombs,
files declaring agents, sizes or a total this code does not run (refused from ``meta`` and the
zip directory before any array is read); each one PolicyFormatError with one line, and one line
from the CLIs. ``validate_action`` accepts only 8 finite JSON numbers; the service never sends a
non-finite action.

Built on the checked-in export tests/data/legacy_reach/policy.npz (no JAX, no MJX): the whole
module takes ~3 s."""

from __future__ import annotations

import hashlib
import io
import json
import os
import time
import tracemalloc
import zipfile

import numpy as np
import pytest

from daddpg_jax.cli import export as export_cli
from daddpg_jax.cli import serve as serve_cli
from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError
from daddpg_jax.deploy.safety import SafetyFilter, SafetyLimits
from daddpg_jax.deploy.server import PolicyClient, PolicyServer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")


def _arrays():
    with np.load(GOOD, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    return arrays, json.loads(str(arrays["meta"]))


def _write(path, arrays, meta=None):
    out = dict(arrays)
    if meta is not None:
        out["meta"] = np.array(json.dumps(meta))
    np.savez(path, **out)
    return str(path)


def _one_line_error(path) -> str:
    with pytest.raises(PolicyFormatError) as e:
        NumpyPolicy.load(path)
    msg = str(e.value)
    assert "\n" not in msg and msg, msg
    return msg


def test_good_file_loads_and_reports_its_sha256():
    """Positive control: the checked-in export loads; its SHA-256 is sha256sum's."""
    p = NumpyPolicy.load(GOOD)
    with open(GOOD, "rb") as f:
        assert p.sha256 == hashlib.sha256(f.read()).hexdigest()
    assert p.info()["policy_sha256"] == p.sha256
    a = p.act(np.zeros((2, 25)), np.full((2, 3), 0.3))
    assert a.shape == (8,) and np.all(np.isfinite(a))


@pytest.mark.parametrize("key,value", [
    ("obs_norm/mean", np.nan), ("obs_norm/std", np.nan), ("goal_norm/mean", np.inf),
    ("goal_norm/std", np.inf), ("obs_norm/std", 0.0), ("goal_norm/std", -1.0),
    ("actor/W0", np.nan), ("actor/b1", -np.inf), ("actor/W1", 1e300)])
def test_nonfinite_or_nonpositive_arrays_are_refused(tmp_path, key, value):
    """A non-finite normaliser mean or std loaded before and answered NaN actions (~10 ms)."""
    arrays, _ = _arrays()
    bad = np.array(arrays[key], np.float64)
    bad.flat[0] = value
    msg = _one_line_error(_write(tmp_path / "bad.npz", {**arrays, key: bad}))
    assert key in msg or "normalizer" in msg or "weights" in msg


@pytest.mark.parametrize("change", [
    {"normalizer": {"clip_obs": float("nan"), "norm_clip": 5.0}},
    {"normalizer": {"clip_obs": 200.0, "norm_clip": float("inf")}},
    {"normalizer": {"clip_obs": -1.0, "norm_clip": 5.0}},
    {"normalizer": None},
    {"obs_size": "25"}, {"obs_size": True}, {"obs_size": 10 ** 9}, {"goal_size": 0},
    {"layer_sizes": [[56, 16], [16]]}, {"layer_sizes": "big"}, {"layer_sizes": []},
    {"layer_sizes": [[56, 10 ** 6], [10 ** 6, 4]]},
    {"format_version": True}, {"task": 7}, {"algo": None}, {"action": []},
    {"action": {"max_delta": -0.05}}, {"obs_layout": {"grip_pos": [0, 99]}},
    {"num_agents": 100},
    {"env": {"dt": -1.0}}, {"env": {"dt": float("nan")}}, {"env": {"dt": 2.0}},
    {"env": {"dt": 0.04, "timestep": 0.02, "n_substeps": 4}}, {"env": []},
    {"env": {"max_delta": float("inf")}},
])
def test_meta_outside_its_schema_is_refused(tmp_path, change):
    """Bad ``meta`` ended in tracebacks (KeyError, TypeError) or loaded (dt = -1); ~10 ms each."""
    arrays, meta = _arrays()
    meta = {**meta, **change}
    if "env" in change and isinstance(change["env"], dict):
        meta["env"] = {**_arrays()[1]["env"], **change["env"]}
    _one_line_error(_write(tmp_path / "bad.npz", arrays, meta))


@pytest.mark.parametrize("raw", [b"", b"PK", b"not a zip", b"PK\x03\x04" + b"\0" * 100])
def test_junk_files_are_refused(tmp_path, raw):
    path = tmp_path / "junk.npz"
    path.write_bytes(raw)
    _one_line_error(path)


def test_meta_that_is_not_json_or_not_a_string(tmp_path):
    arrays, _ = _arrays()
    for meta in (np.array("{not json"), np.array("[1, 2]"), np.array(3.0), np.array("NaN"),
                 np.array('{"format_version": 1, "x": NaN}')):
        _one_line_error(_write(tmp_path / "m.npz", {**arrays, "meta": meta}))
    _one_line_error(_write(tmp_path / "o.npz", {**arrays, "meta": np.array([object()])}))


def test_truncated_files_are_refused(tmp_path):
    """Every cut of the file (about 40 lengths) raises PolicyFormatError, never another
    exception; ~0.3 s."""
    data = open(GOOD, "rb").read()
    for n in list(range(0, len(data), max(1, len(data) // 40))) + [len(data) - 1]:
        path = tmp_path / "cut.npz"
        path.write_bytes(data[:n])
        _one_line_error(path)


def test_wrong_shapes_and_dtypes_are_refused(tmp_path):
    arrays, _ = _arrays()
    for key, value in (("obs_norm/mean", np.zeros((2, 24), np.float32)),
                       ("actor/W0", np.zeros((2, 56, 17), np.float32)),
                       ("actor/b0", np.zeros((2, 16), np.int32)),
                       ("goal_norm/std", np.array(["a", "b"]))):
        msg = _one_line_error(_write(tmp_path / "s.npz", {**arrays, key: value}))
        assert key in msg


def test_member_larger_than_its_declared_shape_is_not_read(tmp_path):
    """A zip bomb: a member of 200 MB (zeros, deflated to ~0.2 MB) where meta declares a
    [2, 25] normaliser. Refused from the zip directory, without inflating it: well under a
    second and a few MB (a 3 MB bomb took 2.1 GB and 15 s before); ~1 s (building the bomb)."""
    path = tmp_path / "bomb.npz"
    big = np.lib.format.header_data_from_array_1_0(np.zeros((2, 25), np.float32))
    big["shape"] = (2, 25 * 1_000_000)
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, big)
    # the export with its observation normaliser's mean replaced by the bomb
    with zipfile.ZipFile(GOOD) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for info in src.infolist():
            if info.filename == "obs_norm/mean.npy":
                with zf.open("obs_norm/mean.npy", "w", force_zip64=True) as f:
                    f.write(head.getvalue())
                    chunk = bytes(1 << 20)
                    for _ in range(200):
                        f.write(chunk)
            else:
                zf.writestr(info.filename, src.read(info.filename))
    assert os.path.getsize(path) < 2_000_000
    tracemalloc.start()
    t0 = time.perf_counter()
    msg = _one_line_error(path)
    took = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert "obs_norm/mean" in msg and "declared shape" in msg
    assert took < 0.5 and peak < 20_000_000, (took, peak)


def test_cli_print_one_line_for_a_bad_policy_file(tmp_path, capsys, monkeypatch):
    """daddpg-serve and daddpg-export (its read-back) print PolicyFormatError's line."""
    arrays, meta = _arrays()
    bad = _write(tmp_path / "bad.npz", arrays, {**meta, "env": {**meta["env"], "dt": -1.0}})
    assert serve_cli.main([bad, "--port", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "dt" in err and len(err.splitlines()) == 1
    monkeypatch.setattr("daddpg_jax.running.export.export_run", lambda *a, **k: bad)
    assert export_cli.main([str(tmp_path), "--out", str(tmp_path / "x.npz")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "Traceback" not in err and len(err.splitlines()) == 1


# -- actions ---------------------------------------------------------------------------------

def test_validate_action_accepts_only_8_finite_numbers():
    """``[1e300]*8`` became inf, ``["1"]*8`` and ``[True]*8`` passed as actions before."""
    f = SafetyFilter(SafetyLimits(workspace_low=np.zeros((2, 3)), workspace_high=np.ones((2, 3)),
                                  max_step=0.01, min_clearance=0.0, deadline_s=0.04))
    for good in ([0.1] * 8, [0] * 8, (1, -1, 0.5, 0, 0, 0, 0, 1), np.zeros(8, np.float32),
                 np.arange(8)):
        out = f.validate_action(good)
        assert out is not None and out.dtype == np.float32 and out.shape == (8,)
    for bad in ([1e300] * 8, [-1e39] + [0.0] * 7, ["1"] * 8, [True] * 8, [None] * 8,
                [0.1] * 7 + [float("nan")], [2 ** 1100] + [0] * 7, np.ones(8, bool),
                np.array(["1"] * 8), np.array([0.1] * 8, object), [[0.1] * 4] * 2, "12345678",
                {"a": 1}, [0.1] * 9, [1j] * 8, np.full(8, 1e300)):
        assert f.validate_action(bad) is None, bad


class _NanPolicy:
    """A policy whose actor answers NaN (as a file with a NaN normaliser did)."""

    def __init__(self, inner):
        self._inner = inner

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def act(self, o, g):
        return np.full(8, np.nan, np.float32)


def test_service_never_sends_a_nonfinite_action():
    """A policy answering NaN gets 500 (counted in /health), never a 200 with NaN; ~0.2 s."""
    policy = NumpyPolicy.load(GOOD)
    o, g = np.zeros((2, 25)), np.full((2, 3), 0.3)
    with PolicyServer(policy, port=0) as honest:  # positive control
        a, info = PolicyClient(honest.url, timeout=5).act(o, g)
        assert a is not None and np.all(np.isfinite(a)), info
    with PolicyServer(_NanPolicy(policy), port=0) as srv:
        c = PolicyClient(srv.url, timeout=5)
        a, info = c.act(o, g)
        assert a is None and "HTTP 500" in info["error"] and "non-finite" in info["error"]
        assert c.health()["nonfinite"] == 1
        c.close()


# -- what a file declares, checked before any array is inflated --------------------------------

def _opened_members(monkeypatch) -> list[str]:
    """The names of the zip members that policy loading opens from now on."""
    opened = []
    real = zipfile.ZipFile.open

    def spy(self, name, *args, **kwargs):
        opened.append(getattr(name, "filename", name))
        return real(self, name, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "open", spy)
    return opened


@pytest.mark.parametrize("change,words", [
    ({"num_agents": 8}, "8 agents for algo daddpg (expected 2)"),
    ({"layer_sizes": [[56, 8192], [8192, 8192], [8192, 4]]}, "more than the limit"),
    ({"layer_sizes": [[56, 16], [17, 4]]}, "actor layer 1 takes 17 inputs"),
    ({"layer_sizes": [[56, 16], [16, 8]]}, "actor output size 8, expected 4"),
    ({"obs_size": 8000, "obs_layout": {}}, "obs_size 8000, but the observation has 25"),
    ({"goal_size": 300}, "goal_size 300, expected 3"),
    ({"num_arms": 8}, "8 arms"), ({"action_size": 32}, "action size 32"),
    ({"env": {"action_history": -1}}, "action_history"),
], ids=["agents", "total", "chain", "output", "obs", "goal", "arms", "action", "history"])
def test_declared_sizes_are_checked_before_any_array_is_read(tmp_path, monkeypatch, change,
                                                             words):
    """A file declaring 8 agents (or layers of 8192, or sizes the robot's observation does not
    have) had every array inflated before that was checked (272 KB -> 564 MB; the format
    allowed ~128 GiB). Now ``meta`` alone is checked against the variant's row and the
    observation code, and the declared total against MAX_INFLATED_BYTES, and only ``meta.npy``
    is opened; the same file with its own ``meta`` opens every array (positive control);
    ~10 ms each."""
    arrays, meta = _arrays()
    meta = {**meta, **change}
    if "env" in change:
        meta["env"] = {**_arrays()[1]["env"], **change["env"]}
    good = _write(tmp_path / "good.npz", arrays)
    bad = _write(tmp_path / "bad.npz", arrays, meta)
    opened = _opened_members(monkeypatch)
    NumpyPolicy.load(good)
    assert {"meta.npy", "actor/W0.npy", "obs_norm/std.npy"} <= set(opened), opened
    opened.clear()
    msg = _one_line_error(bad)
    assert words in msg, msg
    assert opened == ["meta.npy"], opened


def test_inflated_total_is_capped_from_the_zip_directory(tmp_path, monkeypatch):
    """The members' uncompressed sizes in the zip directory count against MAX_INFLATED_BYTES
    before any is opened: with the cap lowered to 10 kB, the export (9.6 kB of float32 arrays)
    loads and the same arrays as float64 (19 kB) are refused, only ``meta.npy`` opened; ~10 ms.
    A policy of the default network (3 hidden layers of 256) is 1.2 MB, far under the real cap."""
    from daddpg_jax.deploy import policy as policy_mod

    arrays, _ = _arrays()
    assert policy_mod.MAX_INFLATED_BYTES == 64 * 1024 * 1024
    monkeypatch.setattr(policy_mod, "MAX_INFLATED_BYTES", 10_000)
    NumpyPolicy.load(GOOD)   # positive control
    wide = {k: (v.astype(np.float64) if k != "meta" else v) for k, v in arrays.items()}
    path = _write(tmp_path / "f64.npz", wide)
    opened = _opened_members(monkeypatch)
    msg = _one_line_error(path)
    assert "zip directory" in msg and "10000" in msg, msg
    assert opened == ["meta.npy"], opened


def test_member_data_must_match_its_header(tmp_path):
    """A member is read as its ``.npy`` header declares: dtype and shape checked from the
    header before the data is inflated, then exactly the bytes they give; data longer or
    shorter than that is refused; ~10 ms."""
    arrays, _ = _arrays()
    npy = io.BytesIO()
    np.save(npy, np.asarray(arrays["obs_norm/mean"], np.float32))
    for name, data in (("long", npy.getvalue() + b"\0" * 8), ("short", npy.getvalue()[:-8])):
        path = tmp_path / f"{name}.npz"
        with zipfile.ZipFile(GOOD) as src, zipfile.ZipFile(path, "w") as zf:
            for info in src.infolist():
                zf.writestr(info.filename, data if info.filename == "obs_norm/mean.npy"
                            else src.read(info.filename))
        msg = _one_line_error(path)
        assert "obs_norm/mean" in msg and "its header declares 200" in msg, msg
