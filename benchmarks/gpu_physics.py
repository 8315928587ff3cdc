"""Env steps/s with ``env.physics=warp`` (MuJoCo Warp on a device) beside ``env.physics=mujoco``.

    python benchmarks/gpu_physics.py --device cuda --n 1024 4096 8192 [--modes oracle student]
        [--seconds 10] [--warmup 20] [--threads 16] [--warp-rays]
    python benchmarks/gpu_physics.py --device cpu --n 4 --seconds 3     # Warp's CPU device: a check

For each mode and N, in one run: the full HikingEnv's steps/s on each backend (``env_rate`` of
``env_throughput.py``: random actions N(0, 0.5), so worlds fall and reset as in early training),
the share of the Warp env's time inside ``WarpWorlds.step`` ("in physics": the rest is the env's
host work) and, measured on the host-step env (whose host arrays follow the simulation), the
Warp backend's physics-only steps/s (``WarpWorlds.step`` alone, the same worlds) launching each
kernel eagerly and replaying the step's captured CUDA graph (``cuda_graph``, the default on a
GPU), the share of that env's time spent in host transfers (the upload of state and targets, the
download of outputs), and the largest qpos difference between the graph's and the eager step
from one state ("graph diff"). The "warp" column runs the env's device-resident step
(``env.resident``, on by default on a CUDA device) with the depth source a student gets by default
(``depth_camera.source=auto``: the host march on Warp's state); the "warp host step" column is the
same env with ``resident=False`` (the state copied to the host and back every step), the comparison
that measures what the resident step gains. ``--warp-rays`` adds, for the student, a column with
the depth cast by Warp's rays on the device (``source=warp``), the comparison that decided ``auto``
(the rays were ~10x slower on an H100). The C backend and the host march run on ``--threads`` CPU
threads.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from env_throughput import env_rate

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.envs.sensors import DepthCameraConfig
from legoh_rl.envs.warp_physics import WarpWorlds


def warp_physics_rate(worlds: WarpWorlds, seconds: float) -> float:
    """World-steps/s of ``worlds.step`` alone (fallen worlds put back on their home states)."""
    n, steps = worlds.num_worlds, 0
    rng = np.random.default_rng(0)
    q0 = np.array(worlds.built.robot.default_joint_pos)
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        worlds.set_joint_targets(q0 + 0.25 * rng.normal(size=(n, q0.size)))
        worlds.step()
        fallen = worlds.qpos[:, 2] < worlds.home_qpos[:, 2] - 0.4
        if fallen.any():
            worlds.reset(fallen, qpos=worlds.home_qpos[fallen])
        steps += 1
    return steps * n / (time.perf_counter() - start)


def transfer_share(env: HikingEnv, seconds: float) -> float:
    """Share of the Warp env's wall time spent in host <-> device transfers."""
    worlds = env.worlds
    spent = [0.0]
    originals = {name: getattr(worlds, name) for name in ("_upload_state", "_download")}

    def timed(fn):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            spent[0] += time.perf_counter() - t
            return out
        return wrapper

    for name, fn in originals.items():
        setattr(worlds, name, timed(fn))
    try:
        start = time.perf_counter()
        env_rate(env, seconds)
        return spent[0] / (time.perf_counter() - start)
    finally:
        for name in originals:
            delattr(worlds, name)


def graph_parity(worlds: WarpWorlds) -> float:
    """Largest |qpos| difference between one control step replayed from the captured CUDA graph
    and the same step launched eagerly, from the same state (nan when the worlds have no graph)."""
    if worlds.resident:
        raise ValueError("graph_parity reads and writes the host arrays, which a resident simulation does not "
                         "follow: build the env with resident=False")
    graph = worlds._graphs.get("step")
    if graph is None:
        return float("nan")
    state = [worlds.qpos.copy(), worlds.qvel.copy(), worlds.ctrl.copy()]
    out = []
    for replay in (False, True):
        worlds.qpos[:], worlds.qvel[:], worlds.ctrl[:] = state
        with worlds.wp.ScopedDevice(worlds.device):
            worlds._upload_state()
            if replay:
                worlds.wp.capture_launch(graph)
            else:
                worlds._launch_control_step()
        worlds._download()
        out.append(worlds.qpos.copy())
    return float(np.abs(out[0] - out[1]).max())


def warp_rates(worlds: WarpWorlds, seconds: float) -> tuple[float, float]:
    """Physics-only world-steps/s of ``worlds`` launching eagerly, then replaying its CUDA graph
    (nan when it has none)."""
    graphs = worlds.cuda_graph
    worlds.cuda_graph = False  # the captured graphs are kept, not replayed
    eager = warp_physics_rate(worlds, seconds)
    worlds.cuda_graph = graphs
    if "step" not in worlds._graphs:
        return eager, float("nan")
    return eager, warp_physics_rate(worlds, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--n", type=int, nargs="+", default=[1024, 4096, 8192])
    parser.add_argument("--modes", nargs="+", default=["oracle", "student"])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--robot", default="h1")
    parser.add_argument("--warp-rays", action="store_true",
                        help="also run the student with Warp's ray-cast depth (depth_camera.source=warp)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads or torch.get_num_threads())
    print(f"device={args.device} robot={args.robot} threads={torch.get_num_threads()}")
    print(f"{'mode':8} {'N':>6} {'mujoco env/s':>13} {'warp env/s':>11} {'warp host step/s':>17} "
          f"{'warp rays/s':>12} {'physics eager/s':>16} {'physics graph/s':>16} {'warp/mujoco':>12} "
          f"{'in physics':>11} {'transfers':>10} {'graph diff':>11}", flush=True)
    for mode in args.modes:
        for n in args.n:
            rates = {}
            # runs: (column, physics, depth source, resident: None = the default for the device)
            runs = [("mujoco", "mujoco", "auto", None), ("warp", "warp", "auto", None),
                    ("host step", "warp", "auto", False)]
            runs += [("rays", "warp", "warp", None)] if mode == "student" and args.warp_rays else []
            for column, physics, source, resident in runs:
                env = HikingEnv(HikingEnvConfig(robot=args.robot, num_envs=n, mode=mode, physics=physics,
                                                num_threads=args.threads, resident=resident,
                                                depth_camera=DepthCameraConfig(source=source),
                                                device=args.device if physics == "warp" else "cpu"))
                rates[column], physics_share = env_rate(env, args.seconds, warmup=args.warmup)
                if column == "warp":
                    in_physics = physics_share
                elif column == "host step":
                    # the host-step env: its host arrays follow the simulation every step (a
                    # resident env's do not), which the transfer timing, the graph-vs-eager
                    # comparison and the physics-only loop (host targets, host fall test) read
                    share = transfer_share(env, min(args.seconds, 3.0))
                    diff = graph_parity(env.worlds)
                    eager, graph = warp_rates(env.worlds, args.seconds)
                del env
            rays = f"{rates['rays']:12.0f}" if "rays" in rates else f"{'-':>12}"
            print(f"{mode:8} {n:6d} {rates['mujoco']:13.0f} {rates['warp']:11.0f} {rates['host step']:17.0f} "
                  f"{rays} {eager:16.0f} {graph:16.0f} {rates['warp'] / rates['mujoco']:12.2f} "
                  f"{in_physics:11.2f} {share:10.2f} {diff:11.2e}", flush=True)


if __name__ == "__main__":
    main()
