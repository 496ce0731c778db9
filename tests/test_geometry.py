"""numkit.geometry against MuJoCo (``mju_quat2Mat``, ``mju_mulQuat``, ``mju_rotVecQuat``,
``mju_mat2Quat``) and scipy's ``Rotation``, and the check that no other module of the packages
writes a quaternion → rotation, a quaternion product or an Euler conversion of its own."""

from __future__ import annotations

import ast
import math
import pathlib
import re

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from numkit import geometry as G

ROOT = pathlib.Path(__file__).resolve().parents[1]
H = math.sqrt(0.5)


def _unit(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q)


#: identity, the half turns about the axes and a diagonal, quarter turns, a tiny turn, w < 0
EDGE = [_unit(q) for q in (
    [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 1, 1, 1], [0, 1, -1, 0],
    [H, H, 0, 0], [H, 0, H, 0], [H, 0, 0, H], [1, 1e-9, -2e-9, 3e-9], [-0.3, 0.5, -0.1, 0.8],
)]


def _quats(n: int = 300, seed: int = 7) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return EDGE + [_unit(q) for q in rng.standard_normal((n, 4))]


def _scipy(q) -> Rotation:
    return Rotation.from_quat(np.asarray(q)[..., [1, 2, 3, 0]])  # scipy is scalar-last


def _same_rotation(a, b, tol: float = 1e-12) -> bool:
    """Unit quaternions ``a`` and ``b`` are the same rotation (q and −q are)."""
    return min(np.abs(np.asarray(a) - b).max(), np.abs(np.asarray(a) + b).max()) < tol


# ------------------------------------------------------------------------------ MuJoCo
@pytest.mark.parametrize("q", _quats())
def test_rotation_matrix_is_mujocos(q):
    ref = np.empty(9)
    mujoco.mju_quat2Mat(ref, q)
    R = np.empty((3, 3))
    G.quat_to_rot(q, R)
    flat = np.empty(9)
    G.quat_to_rot_flat(q, flat)
    assert np.allclose(R.ravel(), ref, rtol=0, atol=1e-15)
    assert np.array_equal(flat, R.ravel())
    assert np.array_equal(np.array(G.quat_to_rot9(*q)), flat)
    assert np.allclose(R, _scipy(q).as_matrix(), rtol=0, atol=1e-14)


def test_product_and_rotation_of_a_vector_are_mujocos():
    rng = np.random.default_rng(11)
    qs = _quats(200, seed=3)
    out, ref = np.empty(4), np.empty(4)
    for a, b in zip(qs, qs[1:] + qs[:1], strict=True):
        G.quat_mul(a, b, out)
        mujoco.mju_mulQuat(ref, a, b)
        assert np.allclose(out, ref, rtol=0, atol=1e-15)
        assert _same_rotation(out, (_scipy(a) * _scipy(b)).as_quat()[[3, 0, 1, 2]])
        v, vo, vr = rng.standard_normal(3), np.empty(3), np.empty(3)
        G.quat_rotate(a, v, vo)
        mujoco.mju_rotVecQuat(vr, v, a)
        assert np.allclose(vo, vr, rtol=0, atol=1e-14)
        assert np.allclose(vo, _scipy(a).apply(v), rtol=0, atol=1e-14)


@pytest.mark.parametrize("q", _quats(100, seed=5))
def test_matrix_to_quaternion_is_mujocos(q):
    """Shepperd's four branches (trace > 0, and each diagonal element the largest)."""
    R, got, ref = np.empty(9), np.empty(4), np.empty(4)
    mujoco.mju_quat2Mat(R, q)
    G.rot_to_quat(R, got)
    mujoco.mju_mat2Quat(ref, R)
    assert _same_rotation(got, ref) and _same_rotation(got, q)


def test_shepperd_visits_every_branch():
    seen = set()
    for q in EDGE[1:4] + [EDGE[0]]:
        R = np.empty(9)
        G.quat_to_rot_flat(q, R)
        tr, d = R[0] + R[4] + R[8], R[[0, 4, 8]]
        seen.add(-1 if tr > 0 else int(np.argmax(d)))
    assert seen == {-1, 0, 1, 2}


# -------------------------------------------------------------------- algebra and maps
def test_conjugate_normalise_exp_and_log():
    rng = np.random.default_rng(2)
    c, d, e, dq, qn = np.empty(4), np.empty(4), np.empty(3), np.empty(4), np.empty(4)
    for q in _quats(100, seed=9):
        G.quat_conj(q, c)
        G.quat_mul(q, c, d)
        assert np.allclose(d, [1, 0, 0, 0], rtol=0, atol=1e-15)
        G.quat_normalize(3.0 * q, qn)
        assert np.allclose(qn, q, rtol=0, atol=1e-15)
        phi = rng.standard_normal(3) * rng.uniform(0.0, 1.0)
        G.quat_exp(phi, dq)
        assert _same_rotation(dq, Rotation.from_rotvec(phi).as_quat()[[3, 0, 1, 2]])
        G.quat_mul(q, dq, qn)  # q_true = q ⊗ Exp(φ): the local error is φ again
        G.quat_log_err(q, qn, e)
        assert np.allclose(e, phi, rtol=0, atol=1e-12)
    G.quat_exp(np.array([1e-14, 0.0, -2e-14]), dq)  # below θ = 1e-12: (1, φ/2)
    assert np.array_equal(dq, [1.0, 5e-15, 0.0, -1e-14])


# ------------------------------------------------------------------------ Euler angles
def _euler_cases(n: int = 200, seed: int = 13) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rpy = np.column_stack([rng.uniform(-math.pi, math.pi, n),
                           rng.uniform(-math.pi / 2, math.pi / 2, n),
                           rng.uniform(-math.pi, math.pi, n)])
    fixed = [[0, 0, 0], [math.pi, 0, 0], [0, 0, math.pi], [0.3, -1.2, 2.9], [-3.0, 1.5, -0.1]]
    return np.vstack([fixed, rpy])


@pytest.mark.parametrize("rpy", _euler_cases())
def test_euler_angles_are_scipys_zyx(rpy):
    roll, pitch, yaw = rpy
    ref = Rotation.from_euler("ZYX", [yaw, pitch, roll])
    q = np.empty(4)
    G.euler_to_quat(roll, pitch, yaw, q)
    assert _same_rotation(q, ref.as_quat()[[3, 0, 1, 2]])
    R = G.euler_to_rots(np.array([roll]), np.array([pitch]), np.array([yaw]))
    assert np.allclose(R[0], ref.as_matrix(), rtol=0, atol=1e-14)
    back = np.array(G.quat_to_euler(*q))
    back_R = np.array(G.rot_to_euler(R[0].ravel()))
    want = ref.as_euler("ZYX")[::-1]
    for got in (back, back_R, G.rots_to_euler(R)[0]):
        d = got - want
        assert np.allclose(np.arctan2(np.sin(d), np.cos(d)), 0.0, rtol=0, atol=1e-9)
    assert G.rot_to_yaw(R[0].ravel()) == back_R[2]


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_gimbal_lock(sign):
    """At θ = ±π/2 the pitch is found (its asin clipped, no NaN) while roll and yaw are not
    defined (only ψ ∓ φ is); a hair away from it the three angles come back."""
    q = np.empty(4)
    G.euler_to_quat(0.4, sign * math.pi / 2, -1.1, q)
    for rpy in (G.quat_to_euler(*q), G.rot_to_euler(np.array(G.quat_to_rot9(*q)))):
        assert abs(rpy[1] - sign * math.pi / 2) < 1e-7 and np.isfinite(rpy).all()
    G.euler_to_quat(0.4, sign * (math.pi / 2 - 1e-4), -1.1, q)
    for rpy in (G.quat_to_euler(*q), G.rot_to_euler(np.array(G.quat_to_rot9(*q)))):
        assert np.allclose(rpy, [0.4, sign * (math.pi / 2 - 1e-4), -1.1], rtol=0, atol=1e-8)


def test_arrays_of_rotations():
    qs = np.array(_quats(50, seed=21))
    R = G.quats_to_rots(2.0 * qs)  # normalised there
    assert np.allclose(R, _scipy(qs).as_matrix(), rtol=0, atol=1e-14)
    q2 = G.rots_to_quats(R)
    assert (q2[:, 0] >= 0).all() and all(_same_rotation(a, b) for a, b in zip(q2, qs, strict=True))


def test_compiled_equals_python():
    """No fastmath: the compiled law gives the plain Python floats' results bit for bit."""
    if not hasattr(G.quat_to_rot9, "py_func"):
        pytest.skip("numba not installed")
    for q in _quats(50, seed=1):
        assert G.quat_to_rot9(*q) == G.quat_to_rot9.py_func(*q)
        assert G.quat_to_euler(*q) == G.quat_to_euler.py_func(*q)


# -------------------------------------------------------------- written once: the AST check
#: functions whose name says they convert quaternions, rotations or Euler angles
NAME = re.compile(r"(^|_)(euler|rpy|ypr|hamilton)|quat.*_(rot|mat|dcm|mul|prod|exp|log|euler)"
                  r"|(^|_)(rot|mat|dcm)s?_.*quat|(^|_)(quat|rot|mat|dcm)s?_.*(yaw|roll|pitch)"
                  r"|(yaw|roll|pitch)s?_(of|from|to)_")
#: the only module allowed to define them
HOME = "numkit/geometry.py"
#: modules allowed to define one anyway (none: it can only stay empty)
ALLOWANCE: dict[str, list[str]] = {}


def _is_call(node: ast.AST, names: tuple[str, ...]) -> bool:
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return (f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")) in names


def _terms(node: ast.AST) -> list[ast.AST]:
    """The terms of a chain of + and −."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add | ast.Sub):
        return _terms(node.left) + _terms(node.right)
    return [node]


def _const(node: ast.AST, v: float) -> bool:
    return isinstance(node, ast.Constant) and node.value == v


def _half(node: ast.AST) -> bool:
    """``e / 2``, ``0.5 * e`` or ``e * 0.5``."""
    return isinstance(node, ast.BinOp) and (
        (isinstance(node.op, ast.Div) and _const(node.right, 2))
        or (isinstance(node.op, ast.Mult) and (_const(node.left, 0.5) or _const(node.right, 0.5))))


def body_signature(fn: ast.AST) -> str | None:
    """What a function's body computes, recognised by the shape of its formulas:

    - ``1 − 2(a + b)`` twice or more: the diagonal of R(q), in a quaternion → rotation or a
      quaternion → Euler conversion;
    - four sums of four products: a Hamilton product;
    - atan2 and asin together: Euler angles from a matrix or a quaternion (the pitch by asin);
    - sin or cos of a half angle twice or more: a quaternion from angles (Euler or the
      exponential map);
    - six or more sin/cos of three or more angles: a rotation from Euler angles.
    """
    nodes = list(ast.walk(fn))
    diag = sum(isinstance(n, ast.BinOp) and isinstance(n.op, ast.Sub) and _const(n.left, 1)
               and isinstance(n.right, ast.BinOp) and isinstance(n.right.op, ast.Mult)
               and _const(n.right.left, 2) and len(_terms(n.right.right)) == 2 for n in nodes)
    if diag >= 2:
        return "quaternion → rotation (1 − 2(a + b) terms)"
    parent = {c: n for n in nodes for c in ast.iter_child_nodes(n)}
    chains = [_terms(n) for n in nodes  # whole chains of + and −, not their parts
              if _terms(n) != [n] and _terms(parent.get(n)) == [parent.get(n)]]
    prod4 = sum(len(t) == 4 and all(isinstance(x, ast.BinOp) and isinstance(x.op, ast.Mult)
                                    for x in t) for t in chains)
    if prod4 >= 4:
        return "quaternion product (four sums of four products)"
    if any(_is_call(n, ("atan2", "arctan2")) for n in nodes) and any(
            _is_call(n, ("asin", "arcsin")) for n in nodes):
        return "Euler angles (atan2 and asin)"
    trig = [n for n in nodes if _is_call(n, ("sin", "cos")) and n.args]
    if sum(_half(n.args[0]) for n in trig) >= 2:
        return "quaternion from half angles"
    if len(trig) >= 6 and len({ast.dump(n.args[0]) for n in trig}) >= 3:
        return "rotation from Euler angles (sin/cos of three angles)"
    return None


def _functions(path: pathlib.Path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node


def geometry_definitions() -> dict[str, list[str]]:
    """Every function outside :mod:`numkit.geometry` whose name or body is a conversion."""
    found: dict[str, list[str]] = {}
    for pkg in ("ag_uav", "controllers", "estimators", "numkit"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel == HOME:
                continue
            for fn in _functions(path):
                why = "name" if NAME.search(fn.name.lower()) else body_signature(fn)
                if why:
                    found.setdefault(rel, []).append(f"{fn.name} (line {fn.lineno}: {why})")
    return found


def test_geometry_is_written_once():
    found = {m: f for m, f in geometry_definitions().items() if f != ALLOWANCE.get(m)}
    assert not found, ("quaternion/rotation/Euler conversions outside numkit.geometry "
                       f"(call numkit.geometry instead): {found}")
    assert not ALLOWANCE


@pytest.mark.parametrize("name", ["quat_to_rot9", "quat_mul", "quat_exp", "euler_to_quat",
                                  "quat_to_euler", "rot_to_euler", "euler_to_rots",
                                  "rots_to_euler"])
def test_the_body_rule_recognises_each_law(name):
    """The body heuristic alone (the name aside) flags each law of numkit.geometry, so a copy
    under another name is caught too."""
    fns = {f.name: f for f in _functions(ROOT / HOME)}
    assert body_signature(fns[name]) is not None


@pytest.mark.parametrize(("name", "flagged"), [
    ("quat_to_rot", True), ("_quat_mul", True), ("rpy_deg", True), ("_euler_quat", True),
    ("euler_zyx_to_rot", True), ("quat_to_rot_np", True), ("rot_to_euler_zyx", True),
    ("rot_log", False), ("mat_mul", False), ("_filterpy_factory", False), ("_yaw_frac", False),
    ("rotor_counts", False), ("_rotation_between", False)])
def test_the_name_rule(name, flagged):
    """The names the conversions had before they moved here are caught; rotor, matrix-product
    and yaw-rate helpers are not."""
    assert (NAME.search(name) is not None) is flagged
