#!/usr/bin/env python3
"""Reference Ceres bundle adjustment (pyceres 2.6 + pycolmap 4.2.1) for BAL text and
libmv binary problems, for comparison against a Rust bundle adjuster.

Usage:
  python3 ceres_ba.py FILE --format bal|libmv --threads N [--max-iterations 100]
          [--linear-solver SPARSE_SCHUR|DENSE_SCHUR|ITERATIVE_SCHUR]
          [--loss trivial|huber] [--libmv-example-options] [--validate]
          [--write-solution PATH]

Prints ONE JSON line on stdout (all library logging goes to stderr).
  initial_cost / final_cost: Ceres cost 0.5 * sum rho(|r|^2) (rho = identity by default)
  iterations: Ceres's "Minimizer iterations" (includes iteration 0, i.e. 1 + LM steps
              recorded); linear_solves / jacobian_evaluations are also given.
  seconds:    wall time of pyceres.solve only (median over --repeat runs).
Solver: Levenberg-Marquardt, SPARSE_SCHUR (automatic ordering), function_tolerance 1e-6,
gradient_tolerance 1e-10, parameter_tolerance 1e-8 (Ceres bundle_adjuster defaults).

How the problems are mapped onto compiled code
----------------------------------------------
Residuals use pycolmap.cost_functions.ReprojErrorCost(RADIAL, obs), an autodiff
C++ cost with parameter blocks [point3D(3), cam_from_world(7), camera(5)]:
  cam_from_world = (qx, qy, qz, qw, tx, ty, tz)   Eigen quaternion, P = q*X + t
  camera         = (f, cx, cy, k1, k2)            COLMAP RADIAL
  u = x/z, v = y/z, r2 = u^2+v^2, d = 1 + k1 r2 + k2 r2^2
  residual = (f d u + cx, f d v + cy) - obs
(The cost returns residual 0 when z < eps, i.e. a point behind the camera; none
of the shipped problems has one at start or end; see behind_camera_at_start/_at_end.)

The pose block gets the manifold COLMAP uses for Rigid3d,
ProductManifold<EigenQuaternionManifold, EuclideanManifold<3>>.  pyceres 2.6
does not bind ProductManifold and a python Manifold subclass cannot override
Plus, so the compiled manifold object is borrowed from a tiny pycolmap
CeresBundleAdjuster problem (problem.get_manifold).  That object is owned twice
(by COLMAP's problem and by the python wrapper), so the process ends with
os._exit() to skip destructors.

BAL (Ceres SnavelyReprojectionError): P = R(w) X + t, p = -P.xy/P.z,
  predicted = f (1 + k1|p|^2 + k2|p|^4) p.  With D = diag(1,-1,-1):
  R' = D R(w), t' = D t, observed' = (x, -y), cx = cy = 0, gives residual'
  = (r.x, -r.y): identical cost.  Each camera has its own (f, 0, 0, k1, k2)
  block with SubsetManifold fixing cx, cy.  Nothing else is fixed (7-dof gauge
  free, as in Ceres's bundle_adjuster).
libmv (Ceres examples/libmv_bundle_adjuster.cc): shared intrinsics block
  (f, cx, cy, k1, k2); k3 = p1 = p2 = 0 in all shipped files (checked, else
  error); f, k1, k2 refined, cx, cy constant.  R from the file (float,
  column-major, not exactly orthonormal) is converted exactly as the example
  does: Ceres RotationMatrixToQuaternion (Shepperd) then normalisation (the
  example goes on to angle-axis, which represents the same unit rotation).
  The pose of the camera of the first usable marker is constant.
"""
import argparse
import json
import os
import sys
import time

import numpy as np

# --------------------------------------------------------------------------------------
# stdout hygiene: C++ libraries may write to fd 1; keep fd 1 -> stderr until the end.
_REAL_STDOUT_FD = os.dup(1)
sys.stdout.flush()
os.dup2(2, 1)

import pyceres  # noqa: E402
import pycolmap  # noqa: E402
from pycolmap import cost_functions as colmap_costs  # noqa: E402

_KEEP_ALIVE = []  # objects that must outlive the solve (borrowed manifold and owner)


def emit_and_exit(obj, code=0):
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(_REAL_STDOUT_FD, 1)
    os.write(1, (json.dumps(obj) + "\n").encode())
    # Skip interpreter teardown: the borrowed manifold is owned by two C++ objects.
    os._exit(code)


# --------------------------------------------------------------------------------------
# Rigid3d manifold borrowed from pycolmap


def rigid3d_manifold():
    opts = pycolmap.SyntheticDatasetOptions()
    opts.num_rigs = 1
    opts.num_cameras_per_rig = 1
    opts.num_frames_per_rig = 2
    opts.num_points3D = 10
    opts.num_points2D_without_point3D = 0
    rec = pycolmap.synthesize_dataset(opts)
    cfg = pycolmap.BundleAdjustmentConfig()
    for iid in rec.images:
        cfg.add_image(iid)
    ba = pycolmap.create_default_ceres_bundle_adjuster(
        pycolmap.BundleAdjustmentOptions(), cfg, rec)
    prob = ba.problem
    man = None
    for fr in rec.frames.values():
        p = fr.rig_from_world.params
        if prob.has_parameter_block(p) and prob.has_manifold(p):
            man = prob.get_manifold(p)
            break
    if man is None or man.ambient_size() != 7 or man.tangent_size() != 6:
        raise RuntimeError("could not obtain COLMAP's Rigid3d manifold")
    # Self-check: the problem Jacobian of a unit prior on a 7-vector equals PlusJacobian.
    x = np.array([0.1, -0.2, 0.3, 0.9, 1.0, 2.0, 3.0])
    x[:4] /= np.linalg.norm(x[:4])
    pr = pyceres.Problem()
    pr.add_residual_block(pyceres.factors.NormalPrior(np.zeros(7), np.eye(7)), None, [x])
    pr.set_manifold(x, man)
    J = pr.evaluate_jacobian()
    M = np.zeros((J.num_rows, J.num_cols))
    rows, cols, vals = np.array(J.rows), np.array(J.cols), np.array(J.values)
    for i in range(J.num_rows):
        M[i, cols[rows[i]:rows[i + 1]]] = vals[rows[i]:rows[i + 1]]
    qx, qy, qz, qw = x[:4]
    E = np.zeros((7, 6))
    E[:4, :3] = [[qw, qz, -qy], [-qz, qw, qx], [qy, -qx, qw], [-qx, -qy, -qz]]
    E[4:, 3:] = np.eye(3)
    if not np.allclose(M, E, atol=1e-12):
        raise RuntimeError("borrowed manifold is not EigenQuaternion x Euclidean(3)")
    _KEEP_ALIVE.extend([rec, cfg, ba, prob, man, pr, x])
    return man


# --------------------------------------------------------------------------------------
# rotation helpers (numpy)


def quat_mul(a, b):
    """Hamilton product of Eigen-order (x, y, z, w) quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def angle_axis_to_quat_xyzw(w):
    th = float(np.linalg.norm(w))
    if th > 0.0:
        s = np.sin(0.5 * th) / th
        return np.array([w[0] * s, w[1] * s, w[2] * s, np.cos(0.5 * th)])
    return np.array([0.5 * w[0], 0.5 * w[1], 0.5 * w[2], 1.0])


def quat_xyzw_to_angle_axis(q):
    """Ceres QuaternionToAngleAxis on a unit quaternion (xyzw)."""
    x, y, z, w = q
    s = np.sqrt(x * x + y * y + z * z)
    if s > 0.0:
        theta = 2.0 * np.arctan2(-s, -w) if w < 0.0 else 2.0 * np.arctan2(s, w)
        k = theta / s
    else:
        k = 2.0
    return np.array([x * k, y * k, z * k])


def ceres_rotation_matrix_to_quat_xyzw(R):
    """Ceres RotationMatrixToQuaternion (2.2), then normalised; returns xyzw."""
    q = np.zeros(4)  # Ceres order w, x, y, z
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace >= 0.0:
        t = np.sqrt(trace + 1.0)
        q[0] = 0.5 * t
        t = 0.5 / t
        q[1] = (R[2, 1] - R[1, 2]) * t
        q[2] = (R[0, 2] - R[2, 0]) * t
        q[3] = (R[1, 0] - R[0, 1]) * t
    else:
        i = 0
        if R[1, 1] > R[0, 0]:
            i = 1
        if R[2, 2] > R[i, i]:
            i = 2
        j = (i + 1) % 3
        k = (j + 1) % 3
        t = np.sqrt(R[i, i] - R[j, j] - R[k, k] + 1.0)
        q[i + 1] = 0.5 * t
        t = 0.5 / t
        q[0] = (R[k, j] - R[j, k]) * t
        q[j + 1] = (R[j, i] + R[i, j]) * t
        q[k + 1] = (R[k, i] + R[i, k]) * t
    q /= np.linalg.norm(q)
    return np.array([q[1], q[2], q[3], q[0]])


def quat_xyzw_to_matrix(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rodrigues(w):
    """Rotation matrices from angle-axis vectors, shape (n,3) -> (n,3,3)."""
    th = np.linalg.norm(w, axis=1)
    out = np.empty((len(w), 3, 3))
    for n in range(len(w)):
        t = th[n]
        K = np.array([[0, -w[n, 2], w[n, 1]], [w[n, 2], 0, -w[n, 0]], [-w[n, 1], w[n, 0], 0]])
        if t < 1e-12:
            out[n] = np.eye(3) + K
        else:
            out[n] = np.eye(3) + np.sin(t) / t * K + (1 - np.cos(t)) / (t * t) * (K @ K)
    return out


# D = diag(1,-1,-1) as a quaternion: 180 degrees about x.
Q_D = np.array([1.0, 0.0, 0.0, 0.0])

# --------------------------------------------------------------------------------------
# readers


def read_bal(path):
    tok = open(path).read().split()
    C, P, N = int(tok[0]), int(tok[1]), int(tok[2])
    obs = np.array(tok[3:3 + 4 * N], dtype=np.float64).reshape(N, 4)
    rest = np.array(tok[3 + 4 * N:3 + 4 * N + 9 * C + 3 * P], dtype=np.float64)
    if len(rest) != 9 * C + 3 * P:
        raise ValueError("truncated BAL file")
    cams = rest[:9 * C].reshape(C, 9)
    pts = rest[9 * C:].reshape(P, 3)
    return dict(cam_idx=obs[:, 0].astype(np.int64), pt_idx=obs[:, 1].astype(np.int64),
                xy=obs[:, 2:4].copy(), cams=cams, pts=pts)


def read_libmv(path):
    b = open(path, "rb").read()
    if b[0:1] == b"v":
        e = "<"
    elif b[0:1] == b"V":
        e = ">"
    else:
        raise ValueError("unknown endian flag %r" % b[0:1])
    space = b[1:2].decode()
    if space not in ("P", "N"):
        raise ValueError("unknown marker space %r" % space)
    off = 2
    intr = np.frombuffer(b, e + "f4", 8, off).astype(np.float64)
    off += 32
    nc = int(np.frombuffer(b, e + "i4", 1, off)[0])
    off += 4
    cdt = np.dtype([("img", e + "i4"), ("R", e + "f4", 9), ("t", e + "f4", 3)])
    cams = np.frombuffer(b, cdt, nc, off)
    off += nc * cdt.itemsize
    npt = int(np.frombuffer(b, e + "i4", 1, off)[0])
    off += 4
    pdt = np.dtype([("trk", e + "i4"), ("X", e + "f4", 3)])
    pts = np.frombuffer(b, pdt, npt, off)
    off += npt * pdt.itemsize
    nm = int(np.frombuffer(b, e + "i4", 1, off)[0])
    off += 4
    mdt = np.dtype([("img", e + "i4"), ("trk", e + "i4"), ("xy", e + "f4", 2)])
    mk = np.frombuffer(b, mdt, nm, off)
    # Later entries with the same index overwrite earlier ones (as in the example).
    cam_R, cam_t = {}, {}
    for c in cams:
        if c["img"] >= 0:
            cam_R[int(c["img"])] = c["R"].astype(np.float64).reshape(3, 3).T  # column-major
            cam_t[int(c["img"])] = c["t"].astype(np.float64)
    pt_X = {}
    for p in pts:
        if p["trk"] >= 0:
            pt_X[int(p["trk"])] = p["X"].astype(np.float64)
    return dict(space=space, intr=intr, cam_R=cam_R, cam_t=cam_t, pt_X=pt_X,
                m_img=mk["img"].astype(np.int64), m_trk=mk["trk"].astype(np.int64),
                m_xy=mk["xy"].astype(np.float64))


# --------------------------------------------------------------------------------------
# independent numpy costs


def loss_rho(s2, loss):
    if loss == "huber":
        return np.where(s2 <= 1.0, s2, 2.0 * np.sqrt(s2) - 1.0)
    return s2


def numpy_cost_bal(d, loss):
    ci, pi = d["cam_idx"], d["pt_idx"]
    cams = d["cams"]
    R = rodrigues(cams[:, :3])
    P = np.einsum("nij,nj->ni", R[ci], d["pts"][pi]) + cams[ci, 3:6]
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1, keepdims=True)
    dist = 1.0 + cams[ci, 7:8] * r2 + cams[ci, 8:9] * r2 * r2
    res = cams[ci, 6:7] * dist * p - d["xy"]
    return 0.5 * float(np.sum(loss_rho(np.sum(res * res, axis=1), loss))), int(np.sum(P[:, 2] >= 0))


def numpy_cost_libmv(d, used, R_of, loss):
    f, cx, cy, k1, k2, k3, p1, p2 = d["intr"]
    img, trk, xy = d["m_img"][used], d["m_trk"][used], d["m_xy"][used]
    Rs = np.stack([R_of(int(i)) for i in img])
    ts = np.stack([d["cam_t"][int(i)] for i in img])
    Xs = np.stack([d["pt_X"][int(t)] for t in trk])
    x = np.einsum("nij,nj->ni", Rs, Xs) + ts
    behind = int(np.sum(x[:, 2] <= 0))
    xn, yn = x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]
    r2 = xn * xn + yn * yn
    r4 = r2 * r2
    r6 = r4 * r2
    rc = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    xd = xn * rc + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * rc + 2.0 * p2 * xn * yn + p1 * (r2 + 2.0 * yn * yn)
    rx = f * xd + cx - xy[:, 0]
    ry = f * yd + cy - xy[:, 1]
    s = 0.5 * float(np.sum(loss_rho(rx * rx + ry * ry, loss)))
    return s, behind


# --------------------------------------------------------------------------------------
# problem builders


def make_loss(loss):
    if loss == "huber":
        lf = pyceres.HuberLoss(1.0)
        _KEEP_ALIVE.append(lf)
        return lf
    return None


def build_bal(d, args, pose_manifold):
    C, P = len(d["cams"]), len(d["pts"])
    poses = np.zeros((C, 7))
    intr = np.zeros((C, 5))
    for c in range(C):
        w, t, f, k1, k2 = d["cams"][c, :3], d["cams"][c, 3:6], *d["cams"][c, 6:9]
        poses[c, :4] = quat_mul(Q_D, angle_axis_to_quat_xyzw(w))
        poses[c, 4:] = (t[0], -t[1], -t[2])
        intr[c] = (f, 0.0, 0.0, k1, k2)
    pts = d["pts"].copy()
    prob = pyceres.Problem()
    loss = make_loss(args.loss)
    model = pycolmap.CameraModelId.RADIAL
    xy = d["xy"]
    for n in range(len(xy)):
        c, p = int(d["cam_idx"][n]), int(d["pt_idx"][n])
        cost = colmap_costs.ReprojErrorCost(model, np.array([xy[n, 0], -xy[n, 1]]))
        prob.add_residual_block(cost, loss, [pts[p], poses[c], intr[c]])
    subset = pyceres.SubsetManifold(5, [1, 2])
    _KEEP_ALIVE.append(subset)
    used_c = np.unique(d["cam_idx"])
    for c in used_c:
        prob.set_manifold(poses[c], pose_manifold)
        prob.set_manifold(intr[c], subset)
    state = dict(poses=poses, intr=intr, pts=pts)
    info = dict(cameras=int(len(used_c)), points=int(len(np.unique(d["pt_idx"]))),
                observations=int(len(xy)), constant_cameras=0,
                res_cam=d["cam_idx"], res_pt=d["pt_idx"])
    return prob, state, info


def usable_markers(d):
    return np.array([(int(i) in d["cam_R"]) and (int(t) in d["pt_X"])
                     for i, t in zip(d["m_img"], d["m_trk"])], dtype=bool)


def build_libmv(d, args, pose_manifold):
    f, cx, cy, k1, k2, k3, p1, p2 = d["intr"]
    if k3 != 0.0 or p1 != 0.0 or p2 != 0.0:
        raise ValueError("k3/p1/p2 non-zero (%g %g %g): COLMAP RADIAL does not match; "
                         "this script only supports k3 = p1 = p2 = 0" % (k3, p1, p2))
    if d["space"] != "P":
        raise ValueError("normalized-space markers ('N'): the example refines no intrinsics "
                         "there; not supported by this script")
    used = usable_markers(d)
    if not used.any():
        raise ValueError("no usable markers")
    imgs = sorted({int(i) for i in d["m_img"][used]})
    trks = sorted({int(t) for t in d["m_trk"][used]})
    cam_row = {i: n for n, i in enumerate(imgs)}
    pt_row = {t: n for n, t in enumerate(trks)}
    poses = np.zeros((len(imgs), 7))
    for i, n in cam_row.items():
        poses[n, :4] = ceres_rotation_matrix_to_quat_xyzw(d["cam_R"][i])
        poses[n, 4:] = d["cam_t"][i]
    pts = np.stack([d["pt_X"][t] for t in trks])
    intr = np.array([f, cx, cy, k1, k2])
    prob = pyceres.Problem()
    loss = make_loss(args.loss)
    model = pycolmap.CameraModelId.RADIAL
    first_cam = None
    res_cam, res_pt = [], []
    for n in np.nonzero(used)[0]:
        i, t = int(d["m_img"][n]), int(d["m_trk"][n])
        cost = colmap_costs.ReprojErrorCost(model, d["m_xy"][n].copy())
        prob.add_residual_block(cost, loss, [pts[pt_row[t]], poses[cam_row[i]], intr])
        res_cam.append(cam_row[i])
        res_pt.append(pt_row[t])
        if first_cam is None:
            first_cam = i
    for n in range(len(imgs)):
        prob.set_manifold(poses[n], pose_manifold)
    prob.set_parameter_block_constant(poses[cam_row[first_cam]])
    subset = pyceres.SubsetManifold(5, [1, 2])  # cx, cy constant; f, k1, k2 refined
    _KEEP_ALIVE.append(subset)
    prob.set_manifold(intr, subset)
    state = dict(poses=poses, intr=intr, pts=pts, imgs=imgs, trks=trks)
    info = dict(cameras=len(imgs), points=len(trks), observations=int(used.sum()),
                constant_cameras=1, constant_camera_image=first_cam,
                res_cam=np.array(res_cam), res_pt=np.array(res_pt))
    return prob, state, info, used


# --------------------------------------------------------------------------------------
# solution writers


def write_bal_solution(path, d, st):
    C = len(st["poses"])
    lines = ["%d %d %d" % (C, len(st["pts"]), len(d["xy"]))]
    for n in range(len(d["xy"])):
        lines.append("%d %d %.17g %.17g" % (d["cam_idx"][n], d["pt_idx"][n], d["xy"][n, 0], d["xy"][n, 1]))
    for c in range(C):
        q = st["poses"][c, :4]
        qb = quat_mul(np.array([-1.0, 0.0, 0.0, 0.0]), q)  # inverse of Q_D
        if qb[3] < 0:
            qb = -qb
        w = quat_xyzw_to_angle_axis(qb / np.linalg.norm(qb))
        t = st["poses"][c, 4:]
        f, _, _, k1, k2 = st["intr"][c]
        for v in (*w, t[0], -t[1], -t[2], f, k1, k2):
            lines.append("%.17g" % v)
    for X in st["pts"]:
        for v in X:
            lines.append("%.17g" % v)
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def write_libmv_solution(path, st):
    q = st["poses"][:, :4]
    np.savez(path, intrinsics_f_cx_cy_k1_k2=st["intr"], image=np.array(st["imgs"]),
             R=np.stack([quat_xyzw_to_matrix(x / np.linalg.norm(x)) for x in q]),
             t=st["poses"][:, 4:], track=np.array(st["trks"]), X=st["pts"])


# --------------------------------------------------------------------------------------


def count_behind(st, info):
    """Residuals whose point has camera-frame z < eps (COLMAP's cost gives 0 there)."""
    q = st["poses"][info["res_cam"], :4]
    X = st["pts"][info["res_pt"]]
    u = q[:, :3]
    w = q[:, 3:4]
    uv = 2.0 * np.cross(u, X)
    P = X + w * uv + np.cross(u, uv) + st["poses"][info["res_cam"], 4:]
    return int(np.sum(P[:, 2] < np.finfo(float).eps))


def parse_ordering(report):
    for line in report.splitlines():
        if line.strip().startswith("Linear solver ordering"):
            parts = line.split()
            return " ".join(parts[3:])  # "AUTOMATIC   given,used"
    return None


def main():
    ap = argparse.ArgumentParser(description="Ceres (pyceres/pycolmap) reference bundle adjustment for BAL text and libmv binary problems; see the module docstring.")
    ap.add_argument("file")
    ap.add_argument("--format", required=True, choices=["bal", "libmv"])
    ap.add_argument("--threads", type=int, required=True)
    ap.add_argument("--max-iterations", type=int, default=100)
    ap.add_argument("--linear-solver", default="SPARSE_SCHUR",
                    choices=["SPARSE_SCHUR", "DENSE_SCHUR", "ITERATIVE_SCHUR"])
    ap.add_argument("--preconditioner", default=None,
                    help="Ceres PreconditionerType name (default SCHUR_JACOBI for ITERATIVE_SCHUR)")
    ap.add_argument("--loss", default="trivial", choices=["trivial", "huber"],
                    help="huber = HuberLoss(1.0), only to reproduce the BAL README reference")
    ap.add_argument("--libmv-example-options", action="store_true",
                    help="libmv_bundle_adjuster.cc solver settings: ITERATIVE_SCHUR + SCHUR_JACOBI "
                         "+ inner iterations + nonmonotonic steps")
    ap.add_argument("--validate", action="store_true",
                    help="add numpy_initial_cost (independent numpy evaluation) to the JSON")
    ap.add_argument("--write-solution", default=None,
                    help="write the solution (BAL: BAL text; libmv: .npz)")
    ap.add_argument("--function-tolerance", type=float, default=1e-6)
    ap.add_argument("--gradient-tolerance", type=float, default=1e-10)
    ap.add_argument("--parameter-tolerance", type=float, default=1e-8)
    ap.add_argument("--repeat", type=int, default=1,
                    help="solve K times from the same start (parameters restored in place); "
                         "'seconds' is then the median, 'seconds_all' lists all")
    ap.add_argument("--verbose", action="store_true", help="Ceres progress + full report on stderr")
    args = ap.parse_args()

    if args.libmv_example_options:
        args.linear_solver = "ITERATIVE_SCHUR"
        args.preconditioner = args.preconditioner or "SCHUR_JACOBI"

    pose_manifold = rigid3d_manifold()
    out = {"file": os.path.basename(args.file), "format": args.format}
    extra = {}
    if args.format == "bal":
        d = read_bal(args.file)
        prob, st, info = build_bal(d, args, pose_manifold)
        if args.validate:
            extra["numpy_initial_cost"], extra["behind_camera_at_start"] = numpy_cost_bal(d, args.loss)
    else:
        d = read_libmv(args.file)
        prob, st, info, used = build_libmv(d, args, pose_manifold)
        if args.validate:
            R_used = {i: quat_xyzw_to_matrix(st["poses"][n, :4]) for n, i in enumerate(st["imgs"])}
            extra["numpy_initial_cost"], extra["behind_camera_at_start"] = numpy_cost_libmv(
                d, used, lambda i: R_used[i], args.loss)
            extra["numpy_initial_cost_raw_float_R"], _ = numpy_cost_libmv(
                d, used, lambda i: d["cam_R"][i], args.loss)

    opts = pyceres.SolverOptions()
    opts.linear_solver_type = getattr(pyceres.LinearSolverType, args.linear_solver)
    if args.preconditioner:
        opts.preconditioner_type = getattr(pyceres.PreconditionerType, args.preconditioner)
    elif args.linear_solver == "ITERATIVE_SCHUR":
        opts.preconditioner_type = pyceres.PreconditionerType.SCHUR_JACOBI
    opts.trust_region_strategy_type = pyceres.TrustRegionStrategyType.LEVENBERG_MARQUARDT
    opts.function_tolerance = args.function_tolerance
    opts.gradient_tolerance = args.gradient_tolerance
    opts.parameter_tolerance = args.parameter_tolerance
    opts.max_num_iterations = args.max_iterations
    opts.num_threads = args.threads
    if args.libmv_example_options:
        opts.use_inner_iterations = True
        opts.use_nonmonotonic_steps = True
    opts.minimizer_progress_to_stdout = args.verbose
    opts.logging_type = (pyceres.LoggingType.PER_MINIMIZER_ITERATION if args.verbose
                         else pyceres.LoggingType.SILENT)

    start = {k: v.copy() for k, v in st.items() if isinstance(v, np.ndarray)}
    times, finals = [], []
    for rep in range(max(1, args.repeat)):
        for k, v in start.items():
            np.copyto(st[k], v)  # in place: the problem holds pointers into these arrays
        summary = pyceres.SolverSummary()
        t0 = time.perf_counter()
        pyceres.solve(opts, prob, summary)
        times.append(time.perf_counter() - t0)
        finals.append(summary.final_cost)
    seconds = float(np.median(times))
    report = summary.FullReport()
    build = None
    for line in report.splitlines():
        if line.startswith("Solver Summary (v "):
            build = line[len("Solver Summary (v "):]
            if build.endswith(")"):
                build = build[:-1]
    if args.verbose:
        sys.stderr.write(report + "\n")

    if args.write_solution:
        if args.format == "bal":
            write_bal_solution(args.write_solution, d, st)
        else:
            write_libmv_solution(args.write_solution, st)

    out.update({
        "cameras": info["cameras"],
        "points": info["points"],
        "observations": info["observations"],
        "initial_cost": summary.initial_cost,
        "final_cost": summary.final_cost,
        # Ceres's "Minimizer iterations": counts iteration 0 (the initial evaluation),
        # so it is 1 + the number of LM steps tried (for CONVERGENCE on the function
        # tolerance the final, rejected step is not counted; see linear_solves).
        "iterations": summary.num_successful_steps + summary.num_unsuccessful_steps,
        "termination": summary.termination_type.name,
        "seconds": seconds,
        "threads": args.threads,
        "linear_solver": summary.linear_solver_type_used.name,
        "ceres_version": getattr(pyceres, "__ceres_version__", None),
    })
    out.update({
        "ceres_build": build,
        "seconds_all": times,
        "final_cost_all": finals,
        "loss": args.loss,
        "linear_solves": summary.num_linear_solves,
        "jacobian_evaluations": summary.num_jacobian_evaluations,
        "residual_evaluations": summary.num_residual_evaluations,
        "successful_steps": summary.num_successful_steps,
        "unsuccessful_steps": summary.num_unsuccessful_steps,
        "message": summary.message,
        "ceres_total_seconds": summary.total_time_in_seconds,
        "preconditioner": summary.preconditioner_type_used.name,
        "sparse_library": summary.sparse_linear_algebra_library_type.name,
        "ordering": parse_ordering(report),
        "inner_iterations": bool(summary.inner_iterations_used),
        "num_threads_used": summary.num_threads_used,
        "constant_cameras": info["constant_cameras"],
        "behind_camera_at_end": count_behind(st, info),
    })
    if "constant_camera_image" in info:
        out["constant_camera_image"] = info["constant_camera_image"]
    out.update(extra)
    emit_and_exit(out)


if __name__ == "__main__":
    try:
        main()
    except SystemExit as e:  # argparse errors / --help
        sys.stderr.flush()
        os.dup2(_REAL_STDOUT_FD, 1)
        os._exit(e.code if isinstance(e.code, int) else 1)
    except BaseException:
        import traceback
        traceback.print_exc()
        sys.stderr.flush()
        os._exit(1)  # never run interpreter teardown (see emit_and_exit)
