"""N worlds of one model stepped by MuJoCo Warp (``env.physics=warp``), on a GPU or Warp's CPU.

:class:`WarpWorlds` keeps :class:`~legoh_rl.envs.physics.BatchedWorlds`' contract, so the env,
its body-state reader, domain randomisation and renderer run on it unchanged: the same live
``(N, ...)`` float64 numpy arrays (``qpos``, ``qvel``, ``ctrl``, ``xpos``, ``xquat``,
``sensordata``, ``actuator_force``, ``cam_xpos``, ``cam_xmat``), the same ``reset``, ``step``,
``per_world``, ``set_const`` and divergence handling. The simulation itself lives in Warp arrays on
``device``; each :meth:`WarpWorlds.step` uploads the state and targets the env may have written
(``qpos``, ``qvel``, ``ctrl``: a few hundred bytes per world) and the model fields domain
randomisation changed, runs ``decimation`` ``mujoco_warp.step`` calls and the kinematics of the
new state, and downloads the outputs. That host round trip is what remains between this backend
and a device-resident env (docs/gpu_physics.md).

How it differs from C MuJoCo (docs/history/warp-feasibility.md): float32 state; heightfield
contacts capped at a few per geom pair, so a landing foot's forces differ while a quiet stance
matches; no instability warnings, so a world is reset as diverged when its state is non-finite or
too fast, or when it overflowed Warp's contact or constraint buffers (``Data.overflow``).

Why one file of ~600 lines: it is one class, :class:`WarpWorlds`, which keeps the whole
``BatchedWorlds`` contract and Warp's compile-ahead and launch recording over the same device buffers.
"""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import mujoco
import numpy as np
import torch

from legoh_rl.envs.physics import MAX_ABS_QVEL, Worlds
from legoh_rl.envs.robots import BuiltModel

__all__ = ["WarpWorlds", "PER_WORLD_FIELDS", "import_mujoco_warp", "warp_device"]

INSTALL_HINT = "pip install 'legoh-rl[gpu]' (mujoco-warp==4.0.0 and warp-lang==1.19.0)"

#: model fields domain randomisation writes per world (legoh_rl/envs/randomization.py)
PER_WORLD_FIELDS = ("geom_friction", "body_mass", "body_ipos", "actuator_gainprm", "actuator_biasprm")
#: what ``mujoco_warp.set_const`` derives from masses and inertias: per world as well
_DERIVED_FIELDS = ("body_subtreemass", "body_invweight0", "dof_invweight0", "actuator_acc0")
#: data arrays the env reads after a step (names shared with MjData and mujoco_warp.Data)
_OUTPUTS = ("qpos", "qvel", "xpos", "xquat", "sensordata", "actuator_force", "cam_xpos", "cam_xmat")


class _Columns:
    """Arrays packed side by side in one (N, width) transfer buffer: ``slices[name] = (a, b)``."""

    def __init__(self, slices: dict[str, tuple[int, int]]) -> None:
        self.slices = slices
        self.width = max((b for _, b in slices.values()), default=0)


def _columns(shapes: dict[str, tuple[int, ...]]) -> _Columns:
    """Consecutive column ranges for arrays of per-world ``shapes`` (each flattened)."""
    slices, at = {}, 0
    for name, shape in shapes.items():
        width = int(np.prod(shape, dtype=np.int64))
        slices[name] = (at, at + width)
        at += width
    return _Columns(slices)


def import_mujoco_warp():
    """``(warp, mujoco_warp)``, initialised quietly.

    Raises:
        ImportError: either package is missing (says what to install).
    """
    try:
        import warp

        warp.config.log_level = warp.LOG_WARNING  # no banner or per-module compile lines
        import mujoco_warp
    except ImportError as err:
        raise ImportError(f"env.physics=warp needs MuJoCo Warp ({err.name} is not installed): {INSTALL_HINT}") from err
    warp.init()
    return warp, mujoco_warp


def warp_device(device: str | torch.device) -> str:
    """Warp's name for a torch device: ``cpu`` -> ``cpu``, ``cuda`` / ``cuda:i`` -> ``cuda:i``.

    Raises:
        ValueError: another device type (names it).
    """
    dev = torch.device(device)
    if dev.type == "cpu":
        return "cpu"
    if dev.type == "cuda":
        return f"cuda:{dev.index or 0}"
    raise ValueError(f"env.physics=warp runs on cpu or cuda devices, got {device!r}")


class WarpWorlds(Worlds):
    """``num_worlds`` copies of a :class:`BuiltModel` stepped together by MuJoCo Warp.

    Args:
        built: the compiled robot + terrain model.
        num_worlds: N, number of worlds (>= 1).
        decimation: physics substeps per control step (>= 1).
        num_threads: CPU threads of the env's other work (depth); Warp's own parallelism is
            its device's. ``None`` = all usable CPUs.
        device: where the simulation runs (``cpu``, ``cuda``, ``cuda:i``).
        nconmax: contacts kept per world (more overflow: that world is reset and counted).
        njmax: constraint rows per world (four per pyramidal contact, plus joint limits).
        compile_workers: threads that compile the step's Warp modules before the first step
            (:meth:`precompile`); ``None``: one per CPU; 0: none (each module compiles at its
            first launch, one after another).
        cuda_graph: replay captured CUDA graphs instead of launching each kernel from Python:
            one of a control step's kernels (``decimation`` x ``mujoco_warp.step``, kinematics,
            camera poses), and one each of a reset's ``reset_data`` (for the persistent world
            mask), ``forward`` and ``set_const``. ``None``: on for a CUDA device, off on the CPU
            (where Warp has no graphs). Each sequence launches eagerly the first time (Warp loads
            its modules then) and is captured the second; a sequence whose capture fails warns
            once and launches eagerly from then on (the others keep their graphs).
        resident: keep the state on the device (``HikingEnvConfig.resident``): a step neither
            uploads the host ``qpos``/``qvel``/``ctrl`` nor downloads the outputs; the env reads
            :attr:`views` and writes targets and pushes as tensors (:meth:`set_joint_targets`,
            :meth:`set_base_xy_velocity`), divergence is found on the device, and a reset writes
            only its worlds' rows. The host arrays are refreshed on request only
            (:meth:`refresh_host`; :meth:`world_data` does it for its world).

    Arrays as :class:`~legoh_rl.envs.physics.BatchedWorlds` (float64 host copies of the float32
    simulation): writes to ``qpos``, ``qvel`` and ``ctrl`` reach the simulation at the next
    :meth:`step`; the outputs are refreshed after every :meth:`step` and reset.

    Attributes:
        diverged_total: worlds reset because they diverged, since construction.
        overflow_total: of those, worlds reset because they overflowed Warp's buffers.

    Raises:
        ImportError: MuJoCo Warp is not installed (says what to install).
    """

    def __init__(
        self,
        built: BuiltModel,
        num_worlds: int,
        decimation: int = 4,
        num_threads: int | None = None,
        device: str | torch.device = "cpu",
        nconmax: int = 64,
        njmax: int = 320,
        compile_workers: int | None = None,
        cuda_graph: bool | None = None,
        resident: bool = False,
    ) -> None:
        self._init_common(built, num_worlds, decimation, num_threads)
        self.resident = bool(resident)
        self.batch = None  # no C batch: the env's depth camera casts obstacle rays with its own caster
        for name, value in (("nconmax", nconmax), ("njmax", njmax)):
            if int(value) < 1:
                raise ValueError(f"{name} must be >= 1, got {value!r}")
        self.wp, self.mjw = import_mujoco_warp()
        self.device = warp_device(device)
        self.torch_device = torch.device("cpu" if self.device == "cpu" else self.device)
        N, mjm = self.num_worlds, self.model
        with self.wp.ScopedDevice(self.device):
            self.m = self.mjw.put_model(mjm, batch_sizes={f: N for f in (*PER_WORLD_FIELDS, *_DERIVED_FIELDS)})
            self.d = self.mjw.put_data(mjm, mujoco.MjData(mjm), nworld=N, nconmax=int(nconmax), njmax=int(njmax))
            self._reset_mask = self.wp.zeros(N, dtype=bool)  # the worlds a reset clears (graph input)
        to_torch = self.wp.to_torch
        self._view = {name: to_torch(getattr(self.d, name)) for name in (*_OUTPUTS, "ctrl", "time", "overflow")}
        self._field_view = {f: to_torch(getattr(self.m, f)) for f in PER_WORLD_FIELDS}
        self._mask_view = to_torch(self._reset_mask)
        self._act_cols = torch.as_tensor(built.actuator_ids, device=self.torch_device)  # ctrl columns of the targets
        one = mujoco.MjData(mjm)
        for name in (*_OUTPUTS, "ctrl"):  # host copies with the C backend's shapes
            setattr(self, name, np.zeros((N, *getattr(one, name).shape)))
        # one float32 transfer each way per step: the state in ([qpos | qvel | ctrl]) and the outputs
        # out ([outputs... | time]), columns as laid out here, through page-locked host buffers on CUDA
        self._in_cols = _columns({name: getattr(self, name).shape[1:] for name in ("qpos", "qvel", "ctrl")})
        self._out_cols = _columns({**{name: getattr(self, name).shape[1:] for name in _OUTPUTS}, "time": ()})
        pin = self.torch_device.type == "cuda"
        self._host_in = torch.zeros((N, self._in_cols.width), dtype=torch.float32, pin_memory=pin)
        self._host_out = torch.zeros((N, self._out_cols.width), dtype=torch.float32, pin_memory=pin)
        self._time = np.zeros(N)
        self._per_world: dict[str, np.ndarray] = {}
        self._dirty: set[str] = set()
        self._sent: dict[str, np.ndarray] = {}  # each per-world field as last uploaded
        self._const_due = False
        self.overflow_total = 0
        if cuda_graph and self.device == "cpu":
            raise ValueError("cuda_graph=True needs a CUDA device; Warp's CPU device has no graphs")
        self.cuda_graph = self.device != "cpu" if cuda_graph is None else bool(cuda_graph)
        self._graphs: dict[str, object] = {}  # captured launch sequences by name ("step", "reset", ...)
        self._loaded: set[str] = set()  # sequences launched eagerly once: their modules are loaded
        self._eager: set[str] = set()  # sequences whose capture failed: launched eagerly for good
        self.compile_workers = (os.cpu_count() or 1) if compile_workers is None else int(compile_workers)
        if self.compile_workers < 0:
            raise ValueError(f"compile_workers must be >= 0, got {compile_workers!r}")
        #: every call handed to :meth:`precompile` (what :meth:`compile_ahead` compiles)
        self.compile_calls: list = []
        with self.wp.ScopedDevice(self.device):
            no_worlds = self.wp.zeros(N, dtype=bool)  # reset_data's kernels for a world mask, as resets call it
        self.precompile([self._launch_control_step, lambda: self.mjw.reset_data(self.m, self.d, reset=no_worlds),
                         lambda: self.mjw.forward(self.m, self.d), lambda: self.mjw.set_const(self.m, self.d)])
        self.reset()

    # ------------------------------------------------------------------ transfers
    def _upload_state(self) -> None:
        """Host ``qpos``, ``qvel``, ``ctrl`` (one float32 copy) and the rows of the per-world model
        fields that changed since their last upload -> the simulation."""
        if not self.resident:  # (a resident simulation's state is written on the device)
            v, host = self._view, self._host_in.numpy()
            for name, (a, b) in self._in_cols.slices.items():
                host[:, a:b] = getattr(self, name).reshape(self.num_worlds, -1)
            state = self._host_in.to(self.torch_device)
            for name, (a, b) in self._in_cols.slices.items():
                v[name].copy_(state[:, a:b].reshape(v[name].shape))
        for field in self._dirty:
            self._upload_field(field)
        self._dirty.clear()
        if self._const_due:
            self._launch("set_const", lambda: self.mjw.set_const(self.m, self.d))
            self._const_due = False

    def _upload_field(self, field: str) -> None:
        """The rows of per-world ``field`` that differ from their last upload -> the simulation
        (domain randomisation changes the reset worlds' rows; the rest need not cross again)."""
        values, sent = self._per_world[field], self._sent.get(field)
        rows = np.arange(self.num_worlds) if sent is None else np.flatnonzero(
            (values != sent).reshape(self.num_worlds, -1).any(axis=1))
        if rows.size == 0:
            return
        view = self._field_view[field]
        src = torch.from_numpy(values[rows]).to(dtype=view.dtype).reshape((rows.size, *view.shape[1:]))
        if rows.size == self.num_worlds:
            view.copy_(src)
        else:
            view[torch.as_tensor(rows, device=self.torch_device)] = src.to(self.torch_device)
        self._sent[field] = values.copy()

    def _download(self, rows: np.ndarray | None = None) -> None:
        """Simulation outputs -> the host arrays, of worlds ``rows`` (all if None), in one float32
        copy."""
        sel = slice(None) if rows is None else torch.as_tensor(rows, device=self.torch_device)
        n = self.num_worlds if rows is None else len(rows)
        packed = torch.cat([self._view[name][sel].reshape(n, -1).to(torch.float32)
                            for name in self._out_cols.slices], dim=1)
        host = self._host_out[:n]
        host.copy_(packed)
        host = host.numpy()
        for name, (a, b) in self._out_cols.slices.items():
            out = self._time if name == "time" else getattr(self, name)
            src = host[:, a:b].reshape((n, *out.shape[1:]))
            if rows is None:
                out[:] = src
            else:
                out[rows] = src

    # ------------------------------------------------------------------ compilation
    def record_launches(self, calls) -> dict[int, tuple[object, set]]:
        """The Warp modules that ``calls`` launch, found without running anything on the device.

        Each call runs once with Warp's ``launch`` recording the kernel it is given (the overload
        a generic kernel would get for its arguments; none for an empty launch, which Warp does
        not load either, such as the tendon kernels of a model without tendons) instead of
        launching it; a device-side loop runs its body once and a device-side if both branches,
        since with nothing running their conditions never change. The state is untouched.

        Args:
            calls: functions of no argument that launch Warp kernels on :attr:`device`.

        Returns:
            ``{id(module): (module, block sizes)}``: each module with the ``block_dim`` values its
            launches asked for (``None``: Warp's default for the device).

        Raises:
            whatever a call raises while recording (Warp's own functions are restored first).
        """
        wp = self.wp
        context = wp._src.context
        launched: dict[int, tuple[object, set]] = {}

        def launch(kernel, dim, inputs=(), outputs=(), adj_inputs=(), adj_outputs=(), device=None, stream=None,
                   adjoint=False, record_tape=True, record_cmd=False, max_blocks=0, block_dim=None):
            if context._normalize_launch_dim(dim)[1] == 0:  # Warp neither loads nor runs an empty launch
                return
            if kernel.is_generic:  # the overload a launch would add for these argument types
                kernel = kernel._add_normalized_overload(kernel.infer_argument_types([*inputs, *outputs]))
            launched.setdefault(id(kernel.module), (kernel.module, set()))[1].add(block_dim)

        def launch_tiled(*args, **kwargs):  # the block size as asked (Warp's resolves it for the device)
            return launch(*args, **kwargs)

        def capture_while(condition, while_body, stream=None, **kwargs):
            while_body(**kwargs)

        def capture_if(condition, on_true=None, on_false=None, stream=None, **kwargs):
            for branch in (on_true, on_false):
                if callable(branch):
                    branch(**kwargs)

        stand_ins = {"launch": launch, "launch_tiled": launch_tiled, "capture_while": capture_while,
                     "capture_if": capture_if}
        originals = {name: getattr(context, name) for name in stand_ins}
        try:
            for name, fn in stand_ins.items():
                setattr(context, name, fn)
                setattr(wp, name, fn)
            with wp.ScopedDevice(self.device):
                for call in calls:
                    call()
        finally:
            for name, fn in originals.items():
                setattr(context, name, fn)
                setattr(wp, name, fn)
        return launched

    def precompile(self, calls: list) -> list[str]:
        """Compile, ``compile_workers`` at a time, the Warp modules that ``calls`` launch.

        Warp compiles a module at its first launch, so a first step compiles MuJoCo Warp's
        modules one after another; the collision kernels MuJoCo Warp builds for this model's geom
        pairs take tens of seconds each on a GPU (docs/gpu_physics.md, "First compile"). Here
        :meth:`record_launches` finds the modules, then ``warp.force_load`` compiles them in
        parallel into Warp's kernel cache. The calls are also kept in :attr:`compile_calls`
        for :meth:`compile_ahead`.

        Args:
            calls: functions of no argument that launch Warp kernels on :attr:`device`.

        Returns:
            the names of the modules recorded and handed to ``warp.force_load`` (empty with
            ``compile_workers=0``, or when the recording failed; a failed recording or compile
            warns, and what is not loaded compiles at its first launch).
        """
        self.compile_calls.extend(calls)
        if self.compile_workers == 0:
            return []
        wp = self.wp
        try:
            launched = self.record_launches(calls)
        except Exception as err:  # noqa: BLE001 - an optimisation only: the first launches compile instead
            warnings.warn(f"WarpWorlds.precompile: recording the launches failed ({type(err).__name__}: {err}); "
                          "modules compile at their first launch", stacklevel=2)
            return []
        device = wp.get_device(self.device)
        by_block: dict[int, list] = {}
        for module, blocks in launched.values():
            for block in {wp._src.context._resolve_launch_block_dim(device, b) for b in blocks}:
                by_block.setdefault(block, []).append(module)
        try:
            for block, modules in by_block.items():
                wp.force_load(device=self.device, modules=modules, block_dim=block,
                              max_workers=min(self.compile_workers, len(modules)))
        except Exception as err:  # noqa: BLE001 - what did not load here compiles at its first launch
            warnings.warn(f"WarpWorlds.precompile: compiling the recorded modules failed ({type(err).__name__}: "
                          f"{err}); the rest compile at their first launch", stacklevel=2)
        return sorted({m.name for m, _ in launched.values()})

    def compile_ahead(self, cache_dir: str | os.PathLike, arch: int = 90, formats: tuple[str, ...] = ("cubin", "ptx"),
                      workers: int | None = None, calls: list | None = None) -> list[Path]:
        """Compile this simulation's Warp modules for a CUDA architecture, on any machine.

        Warp's NVRTC compiles CUDA code without a GPU or driver, so the modules a GPU run would
        compile at its start (:meth:`record_launches` over :attr:`compile_calls`: the control
        step, resets, ``forward``, ``set_const`` and the depth camera's rays) can be compiled
        here, with the block sizes a CUDA launch would use (``block_dim`` or Warp's 256), and
        written in Warp's kernel-cache layout (``<cache_dir>/<warp version>/<module id>/<module
        id>.sm<arch>.cubin`` or ``.ptx``, and its ``.meta``: Warp appends its version to the
        directory ``WARP_CACHE_PATH`` names). A GPU process run with ``WARP_CACHE_PATH=<cache_dir>``
        and the same Warp version then loads them instead of compiling.
        A module's id hashes its code and options, not the device; the model's own kernels
        (its geom pairs' collision kernels) need the same robot and terrain as the run. Kernels
        that only a CUDA device launches (MuJoCo Warp's conditional graph nodes) are not
        recorded here and compile on the GPU as before.

        Args:
            cache_dir: the directory to hand to ``WARP_CACHE_PATH`` (created; existing entries
                are kept).
            arch: the CUDA compute capability, e.g. 90 for H100 and H200, 80 for A100.
            formats: ``cubin`` (what Warp loads when the driver is older than its toolkit) and
                ``ptx`` (what it loads otherwise).
            workers: modules compiled at once; ``None``: :attr:`compile_workers` or one per CPU.
            calls: the calls whose modules to compile; ``None``: :attr:`compile_calls`.

        Returns:
            the files written (binaries only), one per module, block size and format.

        Raises:
            ValueError: an ``arch`` this Warp's NVRTC cannot compile for, or an unknown format.
        """
        wp = self.wp
        wp.init()
        supported = sorted(wp._src.context.runtime.nvrtc_supported_archs or ())
        if int(arch) not in supported:
            raise ValueError(f"arch {arch!r}: this Warp's NVRTC compiles for {supported}")
        bad = [f for f in formats if f not in ("cubin", "ptx")]
        if bad or not formats:
            raise ValueError(f"formats must be some of ('cubin', 'ptx'), got {formats!r}")
        launched = self.record_launches(self.compile_calls if calls is None else calls)
        root = Path(cache_dir) / wp.config.version  # where Warp looks under WARP_CACHE_PATH
        root.mkdir(parents=True, exist_ok=True)

        def build(module, blocks) -> list[Path]:
            out, default = [], module.options["block_dim"]
            try:  # one module per thread: its default block size is set for each variant in turn
                for block in sorted({256 if b is None or b <= 0 else int(b) for b in blocks}):
                    module.options["block_dim"] = block
                    module_dir = root / module.get_module_identifier(block_dim=block)
                    for fmt in formats:
                        out += wp.compile_aot_module(module, arch=int(arch), module_dir=module_dir,
                                                     use_ptx=fmt == "ptx")
            finally:
                module.options["block_dim"] = default
            return out

        n = workers or self.compile_workers or (os.cpu_count() or 1)
        with ThreadPoolExecutor(max_workers=max(1, min(n, len(launched)))) as pool:
            done = pool.map(lambda item: build(*item), launched.values())
            return [Path(p) for paths in done for p in paths]

    # ------------------------------------------------------------------ state
    @property
    def time(self) -> np.ndarray:
        """Simulation time of each world, (N,) s."""
        return self._time

    @property
    def views(self) -> dict[str, torch.Tensor]:
        """The simulation's live arrays as float32 torch tensors on :attr:`torch_device` (no copy):
        ``qpos`` (N, nq), ``qvel`` (N, nv), ``ctrl`` (N, nu), ``xpos`` (N, nbody, 3), ``xquat``
        (N, nbody, 4), ``sensordata`` (N, nsensordata), ``actuator_force`` (N, nu), ``cam_xpos``
        (N, ncam, 3), ``cam_xmat`` (N, ncam, 3, 3), ``time`` (N,). Writes reach the simulation
        directly (with ``resident``; otherwise the next step's upload overwrites them)."""
        return self._view

    def refresh_host(self, rows: np.ndarray | None = None) -> None:
        """Copy the outputs of worlds ``rows`` (all if None) into the host arrays (a resident
        simulation's are not refreshed by steps; otherwise they already are)."""
        if self.resident:
            self._download(None if rows is None else np.asarray(rows, dtype=np.int64).reshape(-1))

    def set_joint_targets(self, q_target) -> None:
        """Set PD joint targets q* of every world, (N, A) rad in leg-joint order: a numpy array
        (the host ``ctrl``, uploaded at the next step) or, resident, a tensor written on the device."""
        if not (self.resident and isinstance(q_target, torch.Tensor)):
            super().set_joint_targets(np.asarray(q_target))
            return
        expected = (self.num_worlds, self.built.actuator_ids.size)
        if tuple(q_target.shape) != expected:
            raise ValueError(f"joint targets must have shape {expected}, got {tuple(q_target.shape)}")
        ctrl = self._view["ctrl"]
        ctrl[:, self._act_cols] = q_target.to(device=ctrl.device, dtype=ctrl.dtype)

    def set_base_xy_velocity(self, ids: np.ndarray, velocity: np.ndarray) -> None:
        """Set the base's world xy velocity of worlds ``ids`` (n,) to ``velocity`` (n, 2) m/s (a
        push; resident: written on the device, only those rows)."""
        if not self.resident:
            super().set_base_xy_velocity(ids, velocity)
            return
        rows = torch.as_tensor(np.asarray(ids, dtype=np.int64), device=self.torch_device)
        qvel = self._view["qvel"]
        qvel[rows, 0:2] = torch.as_tensor(np.asarray(velocity), dtype=qvel.dtype).to(self.torch_device)

    def _reset_to_home(self, idx: np.ndarray) -> None:
        wp, mjw = self.wp, self.mjw
        mask = np.zeros(self.num_worlds, dtype=bool)
        mask[idx] = True
        with wp.ScopedDevice(self.device):
            reset = torch.as_tensor(mask, device=self.torch_device)
            self._mask_view.copy_(reset)
            self._launch("reset", lambda: mjw.reset_data(self.m, self.d, reset=self._reset_mask))
            v = self._view
            v["overflow"][reset] = 0
            if self.resident:  # only these worlds' rows, written where the simulation lives
                rows = torch.as_tensor(idx, device=self.torch_device)
                for name, values in (("qpos", self.home_qpos[idx]), ("qvel", self.home_qvel[idx]),
                                     ("ctrl", np.tile(self.default_targets, (idx.size, 1)))):
                    v[name][rows] = torch.as_tensor(values, dtype=v[name].dtype).to(self.torch_device)
            else:
                self.qpos[idx] = self.home_qpos[idx]
                self.qvel[idx] = self.home_qvel[idx]
                self.ctrl[idx] = self.default_targets
            self._upload_state()
            # positions, velocities, actuation and contact forces of the reset worlds (the others'
            # state is unchanged; only the reset rows are read back)
            self._launch("forward", lambda: mjw.forward(self.m, self.d))
        if not self.resident:
            self._download(idx)

    def step(self, active: np.ndarray | None = None) -> np.ndarray:
        """Advance every world ``decimation`` substeps; reset and count the ones that diverged.
        ``active`` is accepted for the :class:`~legoh_rl.envs.physics.Worlds` interface: one
        kernel launch steps every world, so inactive worlds advance too.

        Returns:
            diverged: (N,) bool, worlds whose state went non-finite or too fast, or which
            overflowed Warp's buffers, during this step; they were reset to their home state.
        """
        with self.wp.ScopedDevice(self.device):
            self._upload_state()
            self._launch("step", self._launch_control_step)
        if self.resident:
            return self._diverged_on_device()
        self._download()
        overflow = self._view["overflow"].cpu().numpy() != 0
        bad = overflow | self.unstable_rows()
        if bad.any():
            idx = np.flatnonzero(bad)
            self.diverged_total += int(idx.size)
            self.overflow_total += int(overflow.sum())
            self._reset_to_home(idx)
        return bad

    def _diverged_on_device(self) -> torch.Tensor:
        """:meth:`step`'s divergence handling for a resident simulation: the test of
        :meth:`unstable_rows` and the overflow flags on the device, one count read back (the
        step's only wait for the device), the diverged worlds reset to their homes.

        Returns:
            (N,) bool tensor on :attr:`torch_device`.
        """
        v = self._view
        overflow = v["overflow"] != 0
        bad = (overflow | ~torch.isfinite(v["qpos"]).all(dim=1) | ~torch.isfinite(v["qvel"]).all(dim=1)
               | (v["qvel"].abs().amax(dim=1) > MAX_ABS_QVEL))
        num_bad, num_overflow = torch.stack([bad.sum(), overflow.sum()]).tolist()
        if num_bad:
            self.diverged_total += int(num_bad)
            self.overflow_total += int(num_overflow)
            self._reset_to_home(torch.nonzero(bad).flatten().cpu().numpy())
        return bad

    def _launch_control_step(self) -> None:
        """The kernels of one control step, launched (or recorded, under a capture)."""
        mjw = self.mjw
        for _ in range(self.decimation):
            mjw.step(self.m, self.d)
        # step leaves positions at the pre-step state: the new state's, as the C backend's
        # mjSTAGE_VEL gives (contact sensors and actuator forces stay those of the last substep)
        mjw.kinematics(self.m, self.d)
        mjw.camlight(self.m, self.d)

    def _launch(self, name: str, launch) -> None:
        """Run the kernel sequence ``launch`` (a function of no argument) on the device: from its
        captured CUDA graph ``name`` when there is one, else eagerly, capturing it on its second
        run (once its modules are loaded) when ``cuda_graph``. A sequence's inputs must live in
        buffers that stay put (the graph replays the same addresses): the state arrays, the
        model's fields, the reset mask."""
        wp = self.wp
        if self.cuda_graph and name not in self._graphs and name in self._loaded and name not in self._eager:
            try:  # a capture records the launches without running them
                with wp.ScopedCapture(device=self.device) as capture:
                    launch()
                self._graphs[name] = capture.graph
            except Exception as err:  # noqa: BLE001 - any capture failure: keep launching this one eagerly
                warnings.warn(f"WarpWorlds: CUDA graph capture of {name!r} failed ({type(err).__name__}: {err}); "
                              "launching its kernels eagerly", stacklevel=3)
                self._eager.add(name)
        graph = self._graphs.get(name) if self.cuda_graph else None
        if graph is not None:
            wp.capture_launch(graph)
        else:
            launch()
            self._loaded.add(name)

    # ------------------------------------------------------------------ model parameters
    def per_world(self, field: str) -> np.ndarray:
        """Per-world copy of a model field, (N, ...), for domain randomisation; what is written
        into it reaches the simulation at the next :meth:`step`.

        Raises:
            ValueError: a field Warp was not given per world (names the ones it was).
        """
        if field not in PER_WORLD_FIELDS:
            raise ValueError(f"WarpWorlds keeps {list(PER_WORLD_FIELDS)} per world, not {field!r}")
        nominal = self.nominal(field)
        if field not in self._per_world:
            self._per_world[field] = np.tile(nominal, (self.num_worlds, *([1] * nominal.ndim)))
        self._dirty.add(field)  # the caller writes into it next
        return self._per_world[field]

    def set_const(self, ids: np.ndarray | None = None) -> None:
        """Recompute derived constants after changing masses or inertias (``mujoco_warp.set_const``,
        at the next step, over every world: unchanged worlds get the same values back)."""
        if ids is not None:
            self._ids(ids)  # validated like the C backend's
        self._const_due = True

    def world_data(self, world: int, data: mujoco.MjData) -> None:
        """World ``world``'s state in ``data``, with its positions computed (for a renderer)."""
        w = int(self._ids(np.array([world]))[0])
        self.refresh_host(np.array([w]))
        data.qpos[:] = self.qpos[w]
        data.qvel[:] = self.qvel[w]
        data.ctrl[:] = self.ctrl[w]
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_camlight(self.model, data)
