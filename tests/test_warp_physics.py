"""env.physics=warp: MuJoCo Warp (on Warp's CPU device here) against the C MuJoCo backend.

Contact-rich humanoid dynamics drift apart eventually (float32 against float64, and Warp keeps
fewer heightfield contacts per geom pair: docs/history/warp-feasibility.md), so the tests compare
what should agree: outputs of the same state, the fall before contact, a held pose over half a
second, the outcome of a landing, the rewards and depth of the same state, and randomised
parameters reaching the simulation. Tolerances: float32 rounding of the state is ~2e-6; the held
pose measured 1.6e-3 after 25 control steps, a 5 cm landing 2.3e-3 after 50.

Why one file of ~550 lines: every test compares the two backends on the same model and pairs of
worlds built here (the ``pair`` fixture), from one state to the evaluation recipe.
"""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from torchrl.envs import check_env_specs

from legoh_rl.envs.config import HikingEnvConfig
from legoh_rl.envs.hiking import HikingEnv
from legoh_rl.envs.randomization import DomainRandConfig
from legoh_rl.envs.robots import ROBOTS
from legoh_rl.envs.sensors import DepthCameraConfig
from legoh_rl.envs.warp_physics import PER_WORLD_FIELDS, WarpWorlds, import_mujoco_warp, warp_device
from legoh_rl.training.checkpoint import load_checkpoint

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
sys.path.insert(0, str(RECIPES))

import oracle_ppo  # noqa: E402
import unified  # noqa: E402

from legoh_rl.training import eval_run  # noqa: E402

N = 4
OFF = DomainRandConfig.off()
wp, _ = import_mujoco_warp()


@wp.kernel
def _add_one(x: wp.array(dtype=float)):
    x[wp.tid()] += 1.0


@wp.kernel
def _add_one_tiled(x: wp.array(dtype=float)):
    _, lane = wp.tid()
    if lane < x.shape[0]:
        x[lane] += 1.0


def cfg_of(name, overrides):
    with initialize_config_dir(config_dir=str(RECIPES / "config"), version_base=None):
        return compose(config_name=name, overrides=overrides)


def make(physics, mode="oracle", domain_rand=OFF, **kw):
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=N, num_threads=1, physics=physics, mode=mode, seed=3,
                                    domain_rand=domain_rand, **kw))
    env.reset()
    env.start_qpos = env.worlds.home_qpos.copy()  # the spawn states, kept for the tests' resets
    return env


@pytest.fixture(scope="module")
def pair():
    """(C, Warp) envs on the same trails, reset to the same states, randomisation off."""
    return make("mujoco"), make("warp")


def same_start(c, w, lift=0.0):
    q = c.start_qpos.copy()
    q[:, 2] += lift
    c.worlds.reset(None, qpos=q)
    w.worlds.reset(None, qpos=q)


def test_physics_name_is_checked():
    with pytest.raises(ValueError, match=r"unknown physics 'bullet'; valid: \['mujoco', 'warp'\]"):
        HikingEnvConfig(physics="bullet")


def test_missing_mujoco_warp_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco_warp", None)  # `import mujoco_warp` raises ImportError
    with pytest.raises(ImportError, match=r"mujoco_warp is not installed.*pip install 'legoh-rl\[gpu\]'"):
        import_mujoco_warp()


def test_warp_device_names():
    assert warp_device("cpu") == "cpu"
    assert warp_device("cuda") == "cuda:0"
    assert warp_device(torch.device("cuda:1")) == "cuda:1"
    with pytest.raises(ValueError, match="cpu or cuda devices, got 'meta'"):
        warp_device("meta")


def test_same_state_gives_the_same_outputs_and_observations(pair):
    c, w = pair
    same_start(c, w)
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 1e-5  # float32 rounding of the state
    for name in ("xpos", "xquat", "cam_xpos", "cam_xmat"):
        assert np.abs(getattr(w.worlds, name) - getattr(c.worlds, name)).max() < 1e-5, name
    td_c, td_w = c.reset(), w.reset()
    for key in ("proprio", "scandots", "privileged", "goal_gps"):
        assert torch.allclose(td_c[key], td_w[key], atol=1e-4), key


def test_fall_before_contact_matches_to_float32_rounding(pair):
    c, w = pair
    same_start(c, w, lift=0.3)
    for _ in range(8):  # 0.16 s: 0.13 m of free fall, no contact yet
        c.worlds.step()
        w.worlds.step()
    assert (c.worlds.qpos[:, 2] < c.start_qpos[:, 2] + 0.25).all()  # it did fall
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 1e-4


def test_held_pose_stays_within_5mm(pair):
    c, w = pair
    same_start(c, w)
    for _ in range(25):  # 0.5 s standing on the PD targets of the default pose
        c.worlds.step()
        w.worlds.step()
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 5e-3
    assert c.worlds.diverged_total == w.worlds.diverged_total == 0


def test_landing_ends_standing_at_the_same_height(pair):
    c, w = pair
    same_start(c, w, lift=0.05)
    for _ in range(50):
        c.worlds.step()
        w.worlds.step()
    for worlds in (c.worlds, w.worlds):
        assert (worlds.qpos[:, 2] > c.start_qpos[:, 2] - 0.1).all()  # standing in both
    assert np.abs(w.worlds.qpos[:, 2] - c.worlds.qpos[:, 2]).max() < 0.01


def test_same_actions_give_the_same_rewards_and_terminations(pair):
    c, w = pair
    td_c, td_w = c.reset(), w.reset()
    same_start(c, w)
    action = 0.3 * torch.randn(N, c.A, generator=torch.Generator().manual_seed(0))
    for _ in range(5):
        td_c = c.step(td_c.set("action", action))["next"]
        td_w = w.step(td_w.set("action", action))["next"]
        assert torch.allclose(td_c["reward"], td_w["reward"], atol=0.02, rtol=0.01)
        assert torch.equal(td_c["done"], td_w["done"])


def test_depth_cast_on_the_device_equals_mujocos_exact_rays():
    """depth_camera.source=warp casts depth with mujoco_warp.rays on the simulation's device: the
    image of the same state is C MuJoCo's exact mj_ray depth (render_exact) to float32 rounding of
    the camera pose (rays agree to ~2e-5 m, i.e. ~5e-6 of the 3.8 m depth range)."""
    c = make("mujoco", mode="student")
    w = make("warp", mode="student", depth_camera=DepthCameraConfig(source="warp"))
    assert w.depth_on_device and isinstance(w.depth, torch.Tensor) and w.depth.device == w.worlds.torch_device
    same_start(c, w)
    w._render_depth(np.ones(N, dtype=bool))
    cam = c.built.camera_id
    exact = c.camera.render_exact(c.worlds.batch, c.worlds.cam_xpos[:, cam], c.worlds.cam_xmat[:, cam].reshape(-1, 3, 3),
                                  np.arange(N))
    diff = np.abs(w.depth.cpu().numpy() - exact)
    assert (diff < 1e-4).mean() > 0.999 and np.median(diff) < 1e-5, (diff.max(), (diff > 1e-4).sum())
    assert 0.1 < float(w.depth.mean()) < 0.99  # terrain in view, not an empty image
    # the step's observation is the device buffer's copy, without a trip through numpy
    td = w.reset()
    assert torch.equal(td["depth"], w.depth) and td["depth"].data_ptr() != w.depth.data_ptr()


@pytest.mark.parametrize("source", ["host", "auto"])
def test_host_depth_on_warp_physics_matches_the_c_backends(source):
    """depth_camera.source=host, and the default auto, keep the host march on physics=warp (the
    faster path measured on an H100): the same image as on C MuJoCo."""
    c = make("mujoco", mode="student")
    w = make("warp", mode="student", depth_camera=DepthCameraConfig(source=source))
    assert not w.depth_on_device and isinstance(w.depth, np.ndarray)
    same_start(c, w)
    c._render_depth(np.ones(N, dtype=bool))
    w._render_depth(np.ones(N, dtype=bool))
    diff = np.abs(w.depth - c.depth)
    assert (diff < 1e-3).mean() > 0.99 and diff.max() < 0.05  # a pixel on an edge may flip
    with pytest.raises(ValueError, match="source='warp' casts the simulation's own rays: it needs physics='warp'"):
        HikingEnvConfig(physics="mujoco", depth_camera=DepthCameraConfig(source="warp"))
    with pytest.raises(ValueError, match="source: unknown depth source 'gpu'"):
        DepthCameraConfig(source="gpu")


def test_device_depth_renders_only_the_ticking_worlds_and_its_noise_resumes():
    """A partial reset refreshes the reset worlds' images alone; noise and dropout come from a seeded
    device generator whose state the env's state_dict carries."""
    cam = DepthCameraConfig(noise_std=0.05, dropout=0.1, source="warp")
    w = make("warp", mode="student", depth_camera=cam)
    td = w.rand_step(w.reset())
    before = w.depth.clone()
    w.worlds.qpos[1, 0] += 0.5  # moved: a fresh frame of world 1 differs from its last one
    w.worlds.reset(np.array([1]), qpos=w.worlds.qpos[[1]])
    w._reset(td.empty().set("_reset", torch.tensor([False, True, False, False]).unsqueeze(-1)))
    keep = [0, 2, 3]
    assert torch.equal(w.depth[keep], before[keep]) and not torch.equal(w.depth[1], before[1])
    assert float((w.depth == 0.0).float().mean()) == pytest.approx(0.1, abs=0.03)  # dropout holes
    state = w.state_dict()
    first = w.camera.render()
    w.load_state_dict(state)
    assert torch.equal(w.camera.render(), first)  # the noise stream resumes exactly
    assert w.camera.generator.initial_seed() == 3  # the env's seed


def test_randomised_parameters_reach_the_simulation():
    """Mass, CoM and motor strength drawn per world: Warp follows C, and ignoring them would not."""
    on = dataclasses.replace(OFF, base_mass=True, base_com=True, motor_strength=True)
    c, w, plain = make("mujoco", domain_rand=on), make("warp", domain_rand=on), make("mujoco")
    assert np.allclose(c.randomizer.privileged(), w.randomizer.privileged())
    assert np.ptp(c.randomizer.motor_strength[:, 0]) > 0.05  # the worlds differ
    q = c.start_qpos.copy()
    for env in (c, w, plain):
        env.worlds.reset(None, qpos=q)
    for _ in range(25):
        for env in (c, w, plain):
            env.worlds.step()
    assert np.abs(w.worlds.qpos - c.worlds.qpos).max() < 5e-3
    assert np.abs(plain.worlds.qpos - c.worlds.qpos).max() > 2e-2
    with pytest.raises(ValueError, match=r"keeps \[.*'geom_friction'.*\] per world, not 'geom_size'"):
        w.worlds.per_world("geom_size")
    assert "body_mass" in PER_WORLD_FIELDS


def test_a_diverged_world_is_reset_alone_and_counted(pair):
    _, w = pair
    worlds = w.worlds
    worlds.reset()
    home = worlds.home_qpos.copy()
    worlds.step()
    before = worlds.qpos.copy()
    worlds.qvel[1, 0] = np.nan
    total = worlds.diverged_total
    bad = worlds.step()
    assert bad.tolist() == [False, True, False, False] and worlds.diverged_total == total + 1
    assert np.allclose(worlds.qpos[1], home[1], atol=1e-5) and worlds.time[1] == 0.0
    assert not np.allclose(worlds.qpos[0], before[0])  # the others stepped on


def test_contact_buffer_overflow_resets_the_world(pair):
    c, _ = pair
    worlds = WarpWorlds(c.built, 2, num_threads=1, nconmax=1, njmax=320)
    worlds.reset(None, qpos=c.start_qpos[:2])
    bad = np.zeros(2, dtype=bool)
    for _ in range(10):  # the feet land with more than one contact each
        bad |= worlds.step()
    assert bad.all() and worlds.overflow_total >= 2 and worlds.diverged_total >= worlds.overflow_total
    assert np.isfinite(worlds.qpos).all()
    with pytest.raises(ValueError, match="nconmax must be >= 1, got 0"):
        WarpWorlds(c.built, 1, nconmax=0)


def _g1_pressed_foot_forces(monkeypatch, foot_sphere_radius):
    """Net contact force on each G1 foot, (2, 3) N, from C MuJoCo and from Warp, with the robot
    lowered until a foot collider is 12 mm into the ground (world 0 of 2)."""
    monkeypatch.setitem(ROBOTS, "g1", dataclasses.replace(ROBOTS["g1"], foot_sphere_radius=foot_sphere_radius))
    envs = [HikingEnv(HikingEnvConfig(robot="g1", num_envs=2, num_threads=1, physics=p, mode="oracle", seed=3,
                                      domain_rand=OFF)) for p in ("mujoco", "warp")]
    for env in envs:
        env.reset()
    c, w = envs
    m, d = c.built.model, mujoco.MjData(c.built.model)
    feet = set(c.built.foot_body_ids.tolist())
    q = c.worlds.home_qpos.copy()
    for _ in range(60):  # 2 mm at a time until the deepest foot contact is 12 mm
        c.worlds.reset(None, qpos=q)
        c.worlds.world_data(0, d)
        mujoco.mj_forward(m, d)
        depth = min((d.contact.dist[i] for i in range(d.ncon)
                     if {m.geom_bodyid[d.contact.geom1[i]], m.geom_bodyid[d.contact.geom2[i]]} & feet), default=1.0)
        if depth < -0.012:
            break
        q[:, 2] -= 0.002
    assert depth < -0.012
    w.worlds.reset(None, qpos=q)
    return [np.stack([e.worlds.sensordata[0, a + 1:a + 4] for a in c.built.foot_sensor_adr]) for e in envs]


def test_g1_pressed_feet_get_the_same_support_from_both_backends(monkeypatch):
    """G1's grown foot spheres (RobotSpec.foot_sphere_radius) keep their centres above the ground
    at the depths a landing reaches, where C MuJoCo and Warp agree (measured: 4-10% apart on the
    vertical force). Menagerie's 5 mm spheres sink below it there, and the backends part: C pushes
    the sphere sideways off the heightfield's prism walls, Warp up off its top (measured: -405 and
    -583 N against -6064 and +7 N)."""
    c, w = _g1_pressed_foot_forces(monkeypatch, 0.02)
    assert np.abs(c[:, 2]).min() > 100.0  # both feet carry the robot
    assert np.allclose(w[:, 2], c[:, 2], rtol=0.15)
    c, w = _g1_pressed_foot_forces(monkeypatch, None)
    assert np.abs(w[:, 2] - c[:, 2]).max() > 2.0 * np.abs(c[:, 2]).max()


def test_world_data_for_the_renderer(pair):
    c, w = pair
    same_start(c, w)
    dc, dw = mujoco.MjData(c.built.model), mujoco.MjData(c.built.model)
    c.worlds.world_data(2, dc)
    w.worlds.world_data(2, dw)
    assert np.abs(dc.xpos - dw.xpos).max() < 1e-5 and np.abs(dc.cam_xpos - dw.cam_xpos).max() < 1e-5


def test_env_specs_on_warp():
    env = HikingEnv(HikingEnvConfig(robot="h1", num_envs=2, num_threads=1, physics="warp"))
    check_env_specs(env, seed=0)


def test_oracle_recipe_trains_and_evaluate_runs_on_warp(tmp_path):
    """``env.physics=warp`` from the command line of oracle_ppo.py and unified.py, with the
    device-resident step (``env.resident=true``, what a CUDA device runs by default), and
    ``physics=warp`` of evaluate.py (the host step on Warp's CPU device)."""
    env = ["env.num_envs=4", "env.categories=[randommix]", "env.variants=1", "env.num_threads=1", "env.physics=warp",
           "env.resident=true", "logger.backend=csv"]
    oracle_ppo.train(cfg_of("oracle_ppo", env + ["collector.steps_per_env=8", "collector.total_frames=32",
                                                 "ppo.num_epochs=1", f"checkpoint.dir={tmp_path / 'ck'}"]))
    state = load_checkpoint(tmp_path / "ck" / "last.pt")
    assert state["config"]["env"]["physics"] == "warp" and state["frames"] == 32
    assert state["config"]["env"]["resident"] is True
    out = eval_run.evaluate(cfg_of("evaluate", [
        f"checkpoint={tmp_path / 'ck' / 'last.pt'}", "physics=warp", "categories=[randommix]", "levels=[0]",
        "robots_per_cell=2", "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}", "video=false",
        "logger.backend=csv"]))
    assert len(out["episodes"]) == 2
    # a student distilled on Warp: its depth cast on the simulation's device, through the
    # student transforms (depth history, perception hold) into TC-ViT
    unified.train(cfg_of("unified", env + [f"teacher={tmp_path / 'ck' / 'last.pt'}", "collector.steps_per_env=10",
                                           "env.depth_camera.source=warp",
                                           "collector.total_frames=40", "dagger_iters=1", "hlm.warmup_iters=1",
                                           "ppo.num_epochs=1", f"checkpoint.dir={tmp_path / 'st'}"]))
    student = load_checkpoint(tmp_path / "st" / "last.pt")
    assert student["config"]["env"]["physics"] == "warp" and student["frames"] == 40
    assert student["config"]["env"]["depth_camera"]["source"] == "warp"
    with pytest.raises(ValueError, match="unknown physics 'gpu'"):
        eval_run.evaluate(cfg_of("evaluate", ["checkpoint=zero", "physics=gpu", "categories=[randommix]",
                                                     "levels=[0]", "robots_per_cell=1", "variants=1", "video=false",
                                                     f"output_dir={tmp_path / 'bad'}", "logger.backend=csv"]))


def _new_loads(monkeypatch):
    """Names of Warp modules that load a new variant from now on (compile or read the cache)."""
    context = sys.modules["warp"]._src.context
    loads, original = [], context.Module.load

    def load(self, device, block_dim=None, *args, **kwargs):
        before = len(self.execs)
        out = original(self, device, block_dim, *args, **kwargs)
        if len(self.execs) != before:
            loads.append(self.name)
        return out

    monkeypatch.setattr(context.Module, "load", load)
    return loads


def test_precompile_loads_every_module_before_the_first_step(pair, monkeypatch):
    """WarpWorlds compiles its step's, resets' and set_const's modules in its constructor (Warp's
    launches recorded, not run); the first steps and a reset then load nothing new, and recording
    leaves the simulation's state and Warp's launch functions as they were."""
    _, w = pair
    worlds = WarpWorlds(w.built, 2, compile_workers=2)
    loads = _new_loads(monkeypatch)
    worlds.step()
    worlds.reset(np.array([1]), qpos=worlds.home_qpos[[1]])
    worlds.step()
    assert loads == []
    wp = worlds.wp
    launch, capture_while = wp.launch, wp.capture_while
    qpos = worlds._view["qpos"].clone()
    names = worlds.precompile([worlds._launch_control_step])
    assert len(names) > 20 and "mujoco_warp._src.forward" in names and any("ccd" in n or "collision" in n for n in names)
    assert torch.equal(worlds._view["qpos"], qpos)  # nothing ran
    assert (wp.launch, wp.capture_while, wp._src.context.launch) == (launch, capture_while, launch)
    with pytest.warns(UserWarning, match="recording the launches failed .*RuntimeError: boom"):
        assert worlds.precompile([lambda: (_ for _ in ()).throw(RuntimeError("boom"))]) == []
    assert wp.launch is launch

    def broken_force_load(**kwargs):
        raise RuntimeError("nvrtc error")

    monkeypatch.setattr(wp, "force_load", broken_force_load)
    with pytest.warns(UserWarning, match="compiling the recorded modules failed .*nvrtc error"):
        assert worlds.precompile([worlds._launch_control_step]) == names  # recorded all the same
    off = WarpWorlds(w.built, 1, compile_workers=0)
    assert off.precompile([off._launch_control_step]) == []
    with pytest.raises(ValueError, match="compile_workers must be >= 0, got -1"):
        WarpWorlds(w.built, 1, compile_workers=-1)


def test_recorded_block_sizes_are_the_ones_the_launches_ask_for(pair):
    """A tiled launch asks for a block size that Warp's CPU device turns into 1; the recording
    keeps what was asked (a CUDA launch uses it, and it is part of the module's cache id)."""
    w = pair[1].worlds
    launched = {module.name: blocks for module, blocks in w.record_launches(w.compile_calls).values()}
    nxn = [blocks for name, blocks in launched.items() if "nxn_broadphase" in name]
    assert nxn == [{w.m.block_dim.nxn_broadphase}] and w.m.block_dim.nxn_broadphase == 128
    assert all(b is None or b >= 32 for blocks in launched.values() for b in blocks)


def test_recorded_modules_are_the_ones_the_launches_load(pair, monkeypatch):
    """What the recording names (module and block size, resolved for the device) is, module id
    for module id, what Warp loads when the same call launches: the ids a kernel cache holds."""
    w = pair[1].worlds
    context = w.wp._src.context
    calls = [lambda: w.mjw.forward(w.m, w.d), lambda: w.mjw.set_const(w.m, w.d)]
    device = w.wp.get_device(w.device)
    recorded = {module.get_module_identifier(block_dim=context._resolve_launch_block_dim(device, b))
                for module, blocks in w.record_launches(calls).values() for b in blocks}
    loaded, original = set(), context.Module.load

    def load(self, device, block_dim=None, *args, **kwargs):
        loaded.add(self.get_module_identifier(block_dim=block_dim))
        return original(self, device, block_dim, *args, **kwargs)

    monkeypatch.setattr(context.Module, "load", load)
    for call in calls:
        call()
    assert len(recorded) > 10 and loaded == recorded


def test_compile_ahead_writes_a_gpu_kernel_cache_without_a_gpu(pair, tmp_path):
    """NVRTC compiles for sm_90 here: each module launched, per block size a CUDA launch would
    use (256 when none is asked), lands as CUBIN and PTX where a Warp process started with
    WARP_CACHE_PATH=<cache_dir> looks (Warp appends its version to that directory)."""
    w = pair[1].worlds
    wp = w.wp
    x = wp.zeros(8, dtype=float, device="cpu")
    calls = [lambda: wp.launch(_add_one, dim=8, inputs=[x]),
             lambda: wp.launch_tiled(_add_one_tiled, dim=[1], inputs=[x], block_dim=64)]
    paths = w.compile_ahead(tmp_path / "cache", arch=90, calls=calls, workers=2)
    probe = "import warp; warp.config.quiet = True; warp.init(); print(warp.config.kernel_cache_dir)"
    looked_up = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                               env=dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "cache"))).stdout.strip()
    lookup = Path(looked_up.splitlines()[-1])
    assert lookup == (tmp_path / "cache" / wp.config.version).resolve()
    module = _add_one.module
    want = set()
    for block in (256, 64):
        ident = module.get_module_identifier(block_dim=block)
        want |= {lookup / ident / f"{ident}.sm90.{fmt}" for fmt in ("cubin", "ptx")}
        assert list((lookup / ident).glob("*.meta")), ident
    assert {p.resolve() for p in paths} == want and all(p.stat().st_size > 0 for p in paths)
    assert x.numpy().sum() == 0.0  # nothing ran
    with pytest.raises(ValueError, match="arch 12: this Warp's NVRTC compiles for"):
        w.compile_ahead(tmp_path / "cache", arch=12, calls=calls)
    with pytest.raises(ValueError, match="formats must be some of"):
        w.compile_ahead(tmp_path / "cache", formats=("sass",), calls=calls)


def test_cuda_graph_captures_on_the_second_run_and_replays_after(pair, monkeypatch):
    """The control flow of cuda_graph (Warp's CPU device has no graphs, so capture and replay are
    stand-ins here), per launch sequence (the step, a reset's reset_data, forward, set_const): the
    first run launches eagerly, the second captures then replays, later runs replay only; a
    sequence whose capture fails warns once and launches eagerly from then on, while the others
    keep their graphs; cuda_graph=False launches eagerly without dropping the graphs."""
    _, w = pair
    with pytest.raises(ValueError, match="cuda_graph=True needs a CUDA device"):
        WarpWorlds(w.built, 1, cuda_graph=True, device="cpu")
    worlds = WarpWorlds(w.built, 2, compile_workers=0)
    assert worlds.cuda_graph is False and worlds._graphs == {}
    calls = []

    class Capture:
        def __init__(self, device):
            calls.append(f"capture on {device}")

        def __enter__(self):
            if "fail" in calls[-2]:
                raise RuntimeError("no graphs here")
            self.graph = f"graph of {calls[-2]}"
            return self

        def __exit__(self, *exc):
            return False

    monkeypatch.setattr(worlds.wp, "ScopedCapture", Capture)
    monkeypatch.setattr(worlds.wp, "capture_launch", lambda graph: calls.append(f"replay {graph}"))
    worlds.cuda_graph = True
    step, fail = (lambda: calls.append("step")), (lambda: calls.append("fail"))
    for _ in range(3):
        worlds._launch("step", step)
    assert calls == ["step", "capture on cpu", "step", "replay graph of step", "replay graph of step"]
    calls.clear()
    worlds._launch("set_const", fail)
    with pytest.warns(UserWarning, match="CUDA graph capture of 'set_const' failed .*no graphs here"):
        worlds._launch("set_const", fail)
    worlds._launch("set_const", fail)
    worlds._launch("step", step)
    assert calls == ["fail", "capture on cpu", "fail", "fail", "replay graph of step"]
    calls.clear()
    worlds.cuda_graph = False
    worlds._launch("step", step)
    assert calls == ["step"] and "step" in worlds._graphs


def test_a_reset_and_a_step_go_through_their_launch_sequences(pair, monkeypatch):
    """A step launches the "step" sequence; a reset "reset" (reset_data on the persistent mask of
    the reset worlds), "forward" and, after masses changed, "set_const": the sequences a CUDA
    device captures."""
    _, w = pair
    worlds = WarpWorlds(w.built, 3, compile_workers=0)
    seen, launch = [], worlds._launch

    def recording(name, fn):
        seen.append(name)
        if name == "reset":
            seen.append(worlds._mask_view.cpu().tolist())
        launch(name, fn)

    monkeypatch.setattr(worlds, "_launch", recording)
    worlds.step()
    worlds.per_world("body_mass")[2, 1] += 1.0
    worlds.set_const(np.array([2]))
    worlds.reset(np.array([2]))
    assert seen == ["step", "reset", [False, False, True], "set_const", "forward"]


def test_only_changed_rows_of_a_randomised_field_are_uploaded(pair):
    """Domain randomisation rewrites the reset worlds' rows of a per-world field; the upload
    sends those rows alone (a value put straight into the simulation's copy of another world's
    row survives it), and the simulation then holds the host's values."""
    _, w = pair
    worlds = WarpWorlds(w.built, 3, compile_workers=0)
    friction = worlds.per_world("geom_friction")
    friction[:, :, 0] = 0.7
    worlds.step()
    view = worlds._field_view["geom_friction"]
    assert torch.allclose(view[..., 0], torch.tensor(0.7, dtype=view.dtype))
    view[0, 0, 0] = 0.123  # the simulation's copy of world 0, changed behind the host's back
    worlds.per_world("geom_friction")[1, :, 0] = 0.4  # world 1 re-randomised
    worlds.step()
    assert float(view[0, 0, 0]) == pytest.approx(0.123)  # row 0 was not sent again
    assert torch.allclose(view[1, :, 0], torch.tensor(0.4, dtype=view.dtype))
    assert torch.allclose(view[2, :, 0], torch.tensor(0.7, dtype=view.dtype))
    worlds.step()  # nothing changed: nothing sent
    assert float(view[0, 0, 0]) == pytest.approx(0.123)


def test_the_gpu_student_experiment_trains_on_warps_cpu_device_and_evaluates_on_mujoco(tmp_path):
    """experiment=student_h1_trails_gpu end to end with a tiny budget on Warp's CPU device (the
    networks on the CPU): the committed oracle distilled on Warp physics, the snapshot evaluated
    on C MuJoCo."""
    tiny = ["experiment=student_h1_trails_gpu", "device=cpu", "env.num_envs=4", "env.num_threads=1",
            "env.categories=[randommix]", "env.variants=1", "env.category_weights=null", "collector.steps_per_env=10",
            "collector.total_frames=80", "dagger_replay.capacity=1000", "dagger_replay.batch_size=16",
            "dagger_minibatches=2", "checkpoint.every=1", "checkpoint.snapshot_every=2", "logger.backend=csv",
            f"checkpoint.dir={tmp_path / 'st'}"]
    out = unified.train(cfg_of("unified", tiny))
    state = load_checkpoint(tmp_path / "st" / "last.pt")
    assert out["iteration"] == 2 and state["config"]["env"]["physics"] == "warp"
    assert state["config"]["experiment_name"] == "student_h1_trails_gpu" and state["config"]["encoder_grad_fraction"] == 0.25
    snapshot = tmp_path / "st" / "snapshots" / "frames000000080.pt"
    result = eval_run.evaluate(cfg_of("evaluate", [
        f"checkpoint={snapshot}", "physics=mujoco", "categories=[randommix]", "levels=[0]", "robots_per_cell=2",
        "variants=1", "num_threads=1", f"output_dir={tmp_path / 'eval'}", "video=false", "logger.backend=csv"]))
    assert len(result["episodes"]) == 2
