#!/usr/bin/env python3
"""IK benchmark: Orocos KDL (Debian's python3-pykdl) and, where it is installed, Pinocchio, on the VaultBot's arm.

The chain is the left UR5's, from ``left_base_link`` to ``left_tool0``, read from the robot's URDF
(yourdfpy) and built joint by joint in each library. Targets are the forward kinematics of seeded
joint configurations within the joints' ranges, so every target is reachable; each solve starts
from the stowed pose, as a servo step or a pose goal would start from where the arm is.

- KDL: ``ChainIkSolverPos_LMA`` (Levenberg-Marquardt), its own solver, from C++;
- Pinocchio: no packaged IK; the closed-loop IK of its documentation (damped least squares on
  ``computeFrameJacobian``, iterated in Python), as a user of it would write.

Reported: solve time p50 / p95, solved fraction (position within 1 mm, rotation within 1 mrad),
and each library's size on disk. Beside them, the production IK itself (``ArmKinematics.ik``: the chain the
manipulator builds, its restarts, and its tolerance, 0.1 mm and 1 mrad), which is what a goal or a servo step
pays; the library rows time one bare solve. Prints a markdown table and writes bench/results/ik.json.
Usage: python bench/bench_ik.py [--targets N]
"""
import argparse
import json
import math
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402
import PyKDL  # noqa: E402

from common import pct, print_table  # noqa: E402
from temoto_robot_manager.manipulation.arm_kinematics import (  # noqa: E402
    IK_TOLERANCE_M, IK_TOLERANCE_RAD, ArmKinematics, KinematicsError)
from vaultbot_sim.kinematics import ROBOT_URDF, TreeModel  # noqa: E402
from vaultbot_sim.spec import ARM_JOINTS, STOW_POSE  # noqa: E402

BASE, TIP = 'left_base_link', 'left_tool0'
JOINTS = ['left_%s_joint' % n for n in ARM_JOINTS]


def chain_joints(model: TreeModel):
    """The joints from BASE to TIP, in order (fixed ones included)."""
    out, link = [], TIP
    while link != BASE:
        j = model._by_child[link]
        out.append(j)
        link = j.parent
    return out[::-1]


def kdl_frame(m: np.ndarray) -> PyKDL.Frame:
    r = m[:3, :3]
    return PyKDL.Frame(PyKDL.Rotation(*r.ravel()), PyKDL.Vector(*m[:3, 3]))


def kdl_chain(model: TreeModel) -> PyKDL.Chain:
    chain = PyKDL.Chain()
    for j in chain_joints(model):
        if j.type in ('revolute', 'continuous'):
            joint = PyKDL.Joint(j.name, PyKDL.Vector(0, 0, 0), PyKDL.Vector(*j.axis), PyKDL.Joint.RotAxis)
        else:
            joint = PyKDL.Joint(j.name, PyKDL.Joint.Fixed) if hasattr(PyKDL.Joint, 'Fixed') else PyKDL.Joint(j.name)
        # the segment's frame: the joint's origin, then its motion (KDL applies the joint after the tip frame of
        # the previous segment; a segment = joint at its root, then a fixed offset to its tip)
        chain.addSegment(PyKDL.Segment(j.child, PyKDL.Joint(j.name + '_origin'), kdl_frame(j.origin)))
        chain.addSegment(PyKDL.Segment(j.child + '_moved', joint, PyKDL.Frame()))
    return chain


def fk(model: TreeModel, q) -> np.ndarray:
    cfg = dict(zip(JOINTS, q))
    return np.linalg.inv(model.link_pose(BASE, cfg)) @ model.link_pose(TIP, cfg)


def pose_error(a: np.ndarray, b: np.ndarray):
    dp = np.linalg.norm(a[:3, 3] - b[:3, 3])
    r = a[:3, :3].T @ b[:3, :3]
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    return dp, angle


def bench_kdl(model, targets, start):
    chain = kdl_chain(model)
    solver = PyKDL.ChainIkSolverPos_LMA(chain)
    q0 = PyKDL.JntArray(6)
    for k, v in enumerate(start):
        q0[k] = v
    times, solved = [], 0
    for m in targets:
        out = PyKDL.JntArray(6)
        t = time.perf_counter()
        solver.CartToJnt(q0, kdl_frame(m), out)
        times.append(time.perf_counter() - t)
        dp, da = pose_error(fk(model, [out[k] for k in range(6)]), m)
        solved += int(dp < 1e-3 and da < 1e-3)
    return times, solved


def bench_production(model, targets, start):
    """The manipulator's own IK (``ArmKinematics.ik``), at its own tolerance; solved when it returns."""
    with open(ROBOT_URDF) as f:
        kin = ArmKinematics(f.read(), BASE, TIP, JOINTS)
    times, solved = [], 0
    for m in targets:
        t = time.perf_counter()
        try:
            q = kin.ik(m, list(start))
        except KinematicsError:
            q = None
        times.append(time.perf_counter() - t)
        if q is not None:
            dp, da = pose_error(fk(model, q), m)
            solved += int(dp <= IK_TOLERANCE_M and da <= IK_TOLERANCE_RAD)
    return times, solved


def bench_pinocchio(model, targets, start):
    import pinocchio as pin          # optional: measured where it is installed (BENCHMARKS.md, "bench_ik.py": a scratch venv)
    full = pin.buildModelFromUrdf(ROBOT_URDF)
    locked = [full.getJointId(n) for n in full.names[1:] if n not in JOINTS]
    arm = pin.buildReducedModel(full, locked, pin.neutral(full))
    data = arm.createData()
    tip, base = arm.getFrameId(TIP), arm.getFrameId(BASE)
    names = list(arm.names)[1:]
    order = [names.index(n) for n in JOINTS]
    times, solved = [], 0
    for m in targets:
        t = time.perf_counter()
        q = np.zeros(arm.nq)
        q[order] = start
        for _ in range(200):
            pin.framesForwardKinematics(arm, data, q)
            here = data.oMf[base].actInv(data.oMf[tip])
            err = pin.log6(here.actInv(pin.SE3(m[:3, :3], m[:3, 3]))).vector
            if np.linalg.norm(err) < 1e-6:
                break
            jac = pin.computeFrameJacobian(arm, data, q, tip, pin.LOCAL)
            q = pin.integrate(arm, q, jac.T @ np.linalg.solve(jac @ jac.T + 1e-6 * np.eye(6), err))
        times.append(time.perf_counter() - t)
        dp, da = pose_error(fk(model, q[order]), m)
        solved += int(dp < 1e-3 and da < 1e-3)
    return times, solved


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--targets', type=int, default=500)
    args = p.parse_args()
    model = TreeModel(ROBOT_URDF)
    rng = np.random.default_rng(41)
    start = np.array([STOW_POSE[n] for n in JOINTS])
    # near the stowed pose, as a servo step or a pose goal nearby would be: within 0.6 rad of it on each joint
    targets = [fk(model, start + rng.uniform(-0.6, 0.6, 6)) for _ in range(args.targets)]
    results, rows = {}, []
    for name, run in (('kdl', bench_kdl), ('pinocchio', bench_pinocchio), ('production', bench_production)):
        try:
            times, solved = run(model, targets, start)
        except ImportError:
            rows.append((name, 'not installed here', '-'))
            continue
        results[name] = {'times': times, 'solved': solved, 'n': len(targets)}
        tolerance = '%.1f mm, %.0f mrad' % (IK_TOLERANCE_M * 1e3, IK_TOLERANCE_RAD * 1e3) if name == 'production' \
            else '1 mm, 1 mrad'
        rows.append(('%s: solve p50 / p95; solved (%s)' % (name, tolerance),
                     '%.3f / %.3f ms; %d / %d' % (pct(times, 50) * 1e3, pct(times, 95) * 1e3, solved, len(targets)),
                     '≤ 1 ms p95'))
    print_table('IK on the left UR5 (from the stowed pose to targets within 0.6 rad a joint)', rows)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'ik.json'), 'w') as f:
        json.dump(results, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
