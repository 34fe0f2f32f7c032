"""The candidate causes of the MJX / C engine gap on grasps that
`experiments.engine_parity.parity` measures: model edits (contact pairs, solver options,
finger geometry and servos), the ways of stepping each engine (`C_MODES`, `MJX_MODES`), and the
named `CANDIDATES`; ``candidate("a+b")`` combines them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import mujoco
import numpy as np

# -- model edits ------------------------------------------------------------------------------

def _pairs_with(m: mujoco.MjModel, word: str) -> np.ndarray:
    """Indices of the contact pairs with a geom whose name contains ``word``."""
    out = []
    for i in range(m.npair):
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or ""
                 for g in (m.pair_geom1[i], m.pair_geom2[i])]
        if any(word in n for n in names):
            out.append(i)
    return np.asarray(out, int)


def _finger_geoms(m: mujoco.MjModel) -> np.ndarray:
    # the finger boxes (not physics version 4's mesh copies: their vertices stay)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) or "" for i in range(m.ngeom)]
    return np.asarray([i for i, n in enumerate(names)
                       if "finger" in n and not n.endswith("_mesh")])


def _solver(iterations: int, ls_iterations: int, tolerance: float | None = None):
    def edit(m):
        m.opt.iterations = iterations
        m.opt.ls_iterations = ls_iterations
        if tolerance is not None:
            m.opt.tolerance = tolerance
    return edit


def _cone(name: str):
    def edit(m):
        m.opt.cone = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL,
                      "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}[name]
    return edit


def _impratio(v: float):
    def edit(m):
        m.opt.impratio = v
    return edit


def _finger_pairs(**fields):
    """Set pair fields (margin, solref, solimp, dim) of every finger pair."""
    def edit(m):
        idx = _pairs_with(m, "finger")
        for name, value in fields.items():
            arr = getattr(m, f"pair_{name}")
            arr[idx] = value
    return edit


def _table_pairs(**fields):
    def edit(m):
        idx = _pairs_with(m, "tabletop")
        for name, value in fields.items():
            getattr(m, f"pair_{name}")[idx] = value
    return edit


def _inflate_fingers(by: float):
    """Finger boxes ``by`` metres larger on every side and finger pairs without margin: the
    contact surface the C engine's 5 mm margin made, as geometry both engines collide."""
    def edit(m):
        for g in _finger_geoms(m):
            m.geom_size[g] += by
            m.geom_rbound[g] = float(np.linalg.norm(m.geom_size[g]))
            m.geom_aabb[g, 3:] = m.geom_size[g]
        m.pair_margin[_pairs_with(m, "finger")] = 0.0
    return edit


def _no_pair(word1: str, word2: str):
    """Switch off the pairs between geoms named with ``word1`` and ``word2`` (margin -1 m:
    never active on either engine)."""
    def edit(m):
        both = np.intersect1d(_pairs_with(m, word1), _pairs_with(m, word2))
        m.pair_margin[both] = -1.0
    return edit


def _pair_fields(word1: str, word2: str, **fields):
    """Set fields (dim, solref, ...) of the pairs between ``word1`` and ``word2`` geoms."""
    def edit(m):
        both = np.intersect1d(_pairs_with(m, word1), _pairs_with(m, word2))
        for name, value in fields.items():
            getattr(m, f"pair_{name}")[both] = value
    return edit


def _finger_servo(kp: float, force: float | None = None):
    """Finger position servos: stiffness kp (gain and bias together) and force limit."""
    def edit(m):
        for i in range(m.nu):
            m.actuator_gainprm[i, 0] = kp
            m.actuator_biasprm[i, 1] = -kp
            if force is not None:
                m.actuator_forcerange[i] = (-force, force)
    return edit


def _chain(*edits):
    def edit(m):
        for e in edits:
            e(m)
    return edit


# -- candidates -------------------------------------------------------------------------------

C_MODES = {
    # name: (StatefulCBackend options or None for the backend as it is)
    "rollout": None,
    "ws_f32": dict(warmstart=True, round_f32=True),
    "f64": dict(warmstart=False, round_f32=False),
    "ws_f64": dict(warmstart=True, round_f32=False),
    "nows_f32": dict(warmstart=False, round_f32=True),  # must equal "rollout" (harness check)
}
MJX_MODES = ("step", "zero_ws")


@dataclasses.dataclass(frozen=True)
class Candidate:
    name: str
    doc: str
    edit: Callable[[mujoco.MjModel], None] | None = None  # applied to the model
    c_mode: str = "rollout"
    mjx_mode: str = "step"
    edit_engines: tuple[str, ...] = ("c", "mjx")  # engines whose model the edit changes
    edit_key: str = ""  # names the edit (default: the candidate's name)

    def side(self, engine: str) -> str:
        """Key of what this candidate changes on one engine (equal keys, equal results)."""
        edit = ((self.edit_key or self.name)
                if (self.edit is not None and engine in self.edit_engines) else "none")
        return f"{edit}/{self.c_mode if engine == 'c' else self.mjx_mode}"


def _cand(name, doc, edit=None, c_mode="rollout", mjx_mode="step", edit_engines=("c", "mjx")):
    return Candidate(name, doc, edit, c_mode, mjx_mode, edit_engines)


CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    _cand("baseline", "the engines as they are"),
    _cand("c_nows_f32", "C stepped with mj_step per env, warmstart zeroed, float32 state "
          "(the rollout backend's semantics: a check of the harness)", c_mode="nows_f32"),
    _cand("c_warmstart", "C carries the solver warmstart across control steps "
          "(float32 state kept)", c_mode="ws_f32"),
    _cand("c_float64", "C keeps its float64 state across control steps (warmstart zeroed)",
          c_mode="f64"),
    _cand("c_plain", "C as plain MuJoCo: float64 state and warmstart carried", c_mode="ws_f64"),
    _cand("mjx_zero_ws", "MJX zeroes the warmstart at every control step, as the C backend",
          mjx_mode="zero_ws"),
    _cand("solver100_c", "C only: iterations 100, ls_iterations 100, tolerance 1e-12 (a "
          "converged C reference; MJX unchanged)", _solver(100, 100, 1e-12),
          edit_engines=("c",)),
    _cand("solver50", "iterations 50, ls_iterations 50, tolerance 1e-10 (both engines)",
          _solver(50, 50, 1e-10)),
    _cand("pyramidal", "pyramidal friction cone (both engines)", _cone("pyramidal")),
    _cand("impratio10", "impratio 10 (both engines)", _impratio(10.0)),
    _cand("margin0", "finger pairs: margin 0 (was 0.005)", _finger_pairs(margin=0.0)),
    _cand("finger_inflate", "finger boxes 5 mm larger on every side, finger pairs margin 0 "
          "(the C engine's contact surface as geometry)", _inflate_fingers(0.005)),
    _cand("no_finger_body", "pot: finger-pot body pairs off", _no_pair("finger", "pot_body")),
    _cand("body_slippery", "pot: finger-pot body pairs friction 0.05 (was 0.5; condim 1 "
          "is not implemented in MJX with elliptic cones)",
          _pair_fields("finger", "pot_body", friction=(0.05, 0.05, 0.005, 1e-4, 1e-4))),
    _cand("bar_slippery", "pickup: finger-bar middle and finger-cap pairs friction 0.05 (was "
          "1.5; the necks keep 1.5)", _chain(
              _pair_fields("finger", "bar_mid", friction=(0.05, 0.05, 0.005, 1e-4, 1e-4)),
              _pair_fields("finger", "bar_cap", friction=(0.05, 0.05, 0.005, 1e-4, 1e-4)))),
    _cand("body_stiff", "pot: finger-pot body pairs solref 0.01 1 (was 0.02 1)",
          _pair_fields("finger", "pot_body", solref=(0.01, 1.0))),
    _cand("condim4", "finger pairs: condim 4 (torsional friction 0.01)", _finger_pairs(dim=4)),
    _cand("solimp_soft", "finger pairs: solimp 0.9 0.95 0.001 (the table's; was 0.95 0.99)",
          _finger_pairs(solimp=(0.9, 0.95, 0.001, 0.5, 2.0))),
    _cand("solref_stiff", "finger pairs: solref 0.01 1 (was 0.02 1)",
          _finger_pairs(solref=(0.01, 1.0))),
    _cand("table_margin", "table pairs: margin 0.005 (was 0)", _table_pairs(margin=0.005)),
    _cand("finger_kp1000", "finger servos kp 1000 (was 300), force limit 20 N kept",
          _finger_servo(1000.0)),
)}


def candidate(name: str) -> Candidate:
    """A candidate by name; ``a+b`` combines candidates (their edits in order; the engine
    modes that differ from the defaults). Raises KeyError naming an unknown part."""
    parts = name.split("+")
    for p in parts:
        if p not in CANDIDATES:
            raise KeyError(p)
    if len(parts) == 1:
        return CANDIDATES[name]
    cs = [CANDIDATES[p] for p in parts]
    edits = [c for c in cs if c.edit is not None]
    c_modes = {c.c_mode for c in cs} - {"rollout"}
    mjx_modes = {c.mjx_mode for c in cs} - {"step"}
    if len(c_modes) > 1 or len(mjx_modes) > 1:
        raise ValueError(f"{name}: conflicting engine modes")
    engines = {e for c in edits for e in c.edit_engines}
    if edits and any(set(c.edit_engines) != engines for c in edits):
        raise ValueError(f"{name}: mixes edits of one engine and of both")
    return Candidate(name, "; ".join(c.doc for c in cs),
                     _chain(*[c.edit for c in edits]) if edits else None,
                     c_modes.pop() if c_modes else "rollout",
                     mjx_modes.pop() if mjx_modes else "step",
                     tuple(sorted(engines)) if edits else ("c", "mjx"),
                     "+".join(c.name for c in edits))
