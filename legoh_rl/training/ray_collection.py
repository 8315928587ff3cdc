"""Collection on a Ray cluster (``collector.backend=ray``): torchrl's ``RayCollector``.

With ``collector.backend=ray`` the ``collector.workers=K`` workers are Ray actors, on this machine or
on the nodes of a Ray cluster (docs/scaling.md, "Many machines: Ray"), each a torchrl
:class:`~torchrl.collectors.Collector` stepping its own :class:`~legoh_rl.training.workers.EnvSlice`
of ``N / K`` worlds: the slicing and seeding of the local backend (worker ``k``: worlds
``k N/K .. (k+1) N/K - 1``, seed ``env.seed + k``, the run's trail grid), so that a checkpoint of
either backend resumes on the other with the same K. The differences:

* a worker reserves ``collector.ray.num_cpus_per_worker`` CPUs from Ray (and
  ``memory_per_worker_gib``) and steps its physics with that many threads (the local backend
  splits ``env.num_threads`` over the K processes of one machine);
* the workers collect on the CPU whatever the run's ``device``: the policy they run is a CPU copy,
  their batches come back as CPU tensors and move to ``device`` in the main process (a worker
  node needs no GPU; the learner may have one);
* torchrl's ``RayWeightSyncScheme`` sends the policy's weights to every worker after each update
  (torch.distributed, gloo over TCP; Ray's object store carries the batches back).

The batches are synchronous (``sync=True``): one ``[N/K, T]`` batch from every worker, concatenated
along the worlds into ``[N, T]`` as the local backend does. The workers' env state (curriculum
levels, counters, random streams) reaches the main process's un-stepped env, and so the logs and
checkpoints, through the same :class:`~legoh_rl.training.workers.WorkerEnvs` as the local backend
(its ``map_fn`` / ``get_distant_attr`` calls become Ray actor calls).

Ray is an optional extra (``pip install 'legoh-rl[ray]'``): this module imports without it, and a
run that asks for ``collector.backend=ray`` without it is refused before any work, with the install
command (:func:`import_ray`).
"""

from __future__ import annotations

import dataclasses
import io
import math
import signal
import threading
import warnings
from collections.abc import Callable, Mapping

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType

from legoh_rl.envs import HikingEnv, HikingEnvConfig
from legoh_rl.training.workers import EnvSlice

with warnings.catch_warnings():  # the package's other collectors (RPC, torch.distributed) warn of deprecations
    warnings.filterwarnings("ignore", message="Creating .*WeightUpdater", category=DeprecationWarning)
    from torchrl.collectors.distributed import RayCollector

__all__ = ["BACKENDS", "RAY_INSTALL", "RayOptions", "collector_backend", "import_ray", "ray_options",
           "WorkerCollector", "RayWorkerCollector", "make_ray_collector"]

#: ``collector.backend`` values: ``local`` (torchrl's MultiSyncCollector, or one process) or ``ray``
BACKENDS = ("local", "ray")
#: what a user installs for ``collector.backend=ray`` (the pinned version is pyproject.toml's ``ray`` extra)
RAY_INSTALL = "pip install 'legoh-rl[ray]'"


@dataclasses.dataclass(frozen=True)
class RayOptions:
    """The ``collector.ray`` section.

    Attributes:
        address: the Ray cluster: ``"local"`` (a fresh Ray instance on this machine, stopped at the
            end of the run), ``"auto"`` (the running cluster that ``ray start`` set up on this
            node), ``"<host>:<port>"`` (a cluster's head node) or ``None`` (Ray's own rule:
            ``RAY_ADDRESS``, else a cluster ``ray start`` set up here, else a fresh local one).
            Ignored when Ray is already initialised in this process (``ray.init`` by the caller).
        num_cpus_per_worker: CPUs each worker reserves from Ray; also its physics threads.
        memory_per_worker_gib: memory (GiB) each worker reserves from Ray for scheduling (not a
            limit); ``None``: no reservation.
    """

    address: str | None = "local"
    num_cpus_per_worker: int = 1
    memory_per_worker_gib: float | None = 2.0

    def init_config(self) -> dict:
        """The keyword arguments of ``ray.init`` (a fresh local instance starts without its dashboard)."""
        config: dict = {"address": self.address}
        if self.address == "local":
            config["include_dashboard"] = False
        return config

    def remote_config(self) -> dict:
        """The keyword arguments of ``ray.remote`` for one worker actor (no GPU: workers collect on the CPU)."""
        config: dict = {"num_cpus": self.num_cpus_per_worker, "num_gpus": 0}
        if self.memory_per_worker_gib is not None:
            config["memory"] = int(self.memory_per_worker_gib * 2**30)
        return config


def collector_backend(collector: Mapping) -> str:
    """``collector.backend`` (``"local"`` when absent), checked.

    Raises:
        ValueError: not one of :data:`BACKENDS` (names the value).
    """
    backend = collector.get("backend", "local")
    if backend not in BACKENDS:
        raise ValueError(f"collector.backend must be one of {list(BACKENDS)}, got {backend!r}")
    return backend


def ray_options(section: Mapping | None) -> RayOptions:
    """The ``collector.ray`` section (``None``: the defaults), checked.

    Raises:
        ValueError: an unknown key, an ``address`` that is not a non-empty string (or null), a
            ``num_cpus_per_worker`` that is not a positive integer, a ``memory_per_worker_gib`` that
            is not a positive number (or null); each message names the setting and its value.
    """
    section = dict(section or {})
    known = [f.name for f in dataclasses.fields(RayOptions)]
    unknown = sorted(set(section) - set(known))
    if unknown:
        raise ValueError(f"collector.ray has no setting {unknown[0]!r}: its settings are {known}")
    options = RayOptions(**section)
    address = options.address
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ValueError("collector.ray.address must be local, auto, <host>:<port> or null, "
                         f"got {address!r}")
    cpus = options.num_cpus_per_worker
    if not isinstance(cpus, int) or isinstance(cpus, bool) or cpus < 1:
        raise ValueError(f"collector.ray.num_cpus_per_worker must be a positive integer, got {cpus!r}")
    memory = options.memory_per_worker_gib
    if memory is not None and (isinstance(memory, bool) or not isinstance(memory, int | float) or not memory > 0
                               or not math.isfinite(memory)):
        raise ValueError(f"collector.ray.memory_per_worker_gib must be a positive number of GiB or null, got {memory!r}")
    return options


def import_ray():
    """The ``ray`` module.

    Raises:
        ImportError: Ray is not installed; the message names the install command.
    """
    try:
        import ray
    except ImportError as err:
        raise ImportError(f"collector.backend=ray needs Ray, which is not installed here: {RAY_INSTALL} "
                          "(on every node of the cluster), or collector.backend=local") from err
    return ray


def _on_cpu(obj):
    """A copy of ``obj`` (anything picklable: modules, factories holding modules) with every tensor
    on the CPU: what a worker without a GPU can unpickle.

    The one ``torch.load`` of the project without ``weights_only=True`` (checkpoints keep to it:
    :func:`~legoh_rl.training.checkpoint.load_checkpoint`), and it need not: the bytes it reads are
    the ones ``torch.save`` wrote two lines above, in memory, from objects of this process; they
    never touch a file or the network, so nothing from anyone else can reach this unpickler. And it
    cannot: a module or an env factory is not a tensor or a plain container. The weights sent to
    the workers after each update go as tensors (torchrl's ``RayWeightSyncScheme``, no pickle);
    what Ray itself pickles between the processes of a cluster you started is within Ray's trust
    model (every node of a cluster runs code for every other), not a shared file."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    buffer.seek(0)
    return torch.load(buffer, map_location="cpu", weights_only=False)


class _Batches:
    """The RayCollector's postproc: its ``[K, N/K, T]`` stack of the workers' batches as ``[N, T]``
    (worker ``k``'s worlds at ``k N/K .. (k+1) N/K - 1``), on the run's device."""

    def __init__(self, device: torch.device) -> None:
        self.device = device

    def __call__(self, data: TensorDictBase) -> TensorDictBase:
        return data.flatten(0, 1).to(self.device)


class WorkerCollector(Collector):
    """What each Ray actor runs: torchrl's :class:`~torchrl.collectors.Collector`, with a one-line
    ``repr`` (Ray prints an actor's ``repr`` to name its log lines; the collector's spans pages)."""

    def __repr__(self) -> str:
        return f"WorkerCollector(worker={self.worker_idx})"


class RayWorkerCollector(RayCollector):
    """torchrl's :class:`~torchrl.collectors.distributed.RayCollector` with what the training loop
    asks of a collector of worker slices (as of a :class:`~torchrl.collectors.MultiSyncCollector`).

    Args:
        *args, **kwargs: :class:`RayCollector`'s.
        trained: the policy the main process trains, whose weights :meth:`update_policy_weights_`
            sends (the workers run a CPU copy of it).
        owns_ray: this collector started Ray (``ray.init``) and stops it in :meth:`shutdown`.
    """

    def __init__(self, *args, trained: torch.nn.Module, owns_ray: bool, **kwargs) -> None:
        self._trained, self._owns_ray = trained, owns_ray
        try:
            super().__init__(*args, **kwargs)
        except BaseException:  # e.g. a worker's env failed to build: stop the workers already started
            self._stop()
            raise

    def reset(self) -> None:
        """Reset every worker's envs (as :meth:`MultiSyncCollector.reset` does): its worlds start
        anew from its env's current state (curriculum levels, random stream)."""
        self.map_fn("reset")

    def update_policy_weights_(self, policy_or_weights=None, **kwargs) -> None:
        """Send weights to every worker: with no argument, the trained policy's current parameters
        and buffers (a ``TensorDict`` of them, taken to the CPU on the way)."""
        if policy_or_weights is None and not kwargs:
            policy_or_weights = TensorDict.from_module(self._trained).data
        super().update_policy_weights_(policy_or_weights, **kwargs)

    def shutdown(self, timeout: float | None = None, shutdown_ray: bool = False) -> None:
        """Stop the workers (and Ray, when this collector started it); safe to call twice."""
        super().shutdown(timeout=timeout, shutdown_ray=shutdown_ray)
        self._stop()

    def _stop(self) -> None:
        """Kill the workers started so far and, when this collector started Ray, stop it."""
        import ray

        if ray.is_initialized():
            for actor in getattr(self, "_remote_collectors", ()):
                ray.kill(actor, no_restart=True)
            self._remote_collectors = []
            lease = getattr(self, "_runtime_lease", None)  # torchrl's count of Ray's users (released once)
            if lease is not None:
                lease.release()
            if self._owns_ray:
                ray.shutdown()
        self._owns_ray = False

    def __del__(self) -> None:
        # RayCollector's own finaliser calls Ray, which would start a new Ray instance once this
        # collector stopped the one it started: nothing is left to release then
        import ray

        if ray.is_initialized():
            super().__del__()


def make_ray_collector(cfg: HikingEnvConfig, workers: int, wrap: Callable[[HikingEnv], EnvBase] | None,
                       policy: torch.nn.Module, frames_per_batch: int, total_frames: int, options: RayOptions,
                       device: torch.device, exploration_type: ExplorationType = ExplorationType.RANDOM,
                       **kwargs) -> RayWorkerCollector:
    """A :class:`RayWorkerCollector` over ``workers`` Ray actors, each a
    :class:`~torchrl.collectors.Collector` of one :class:`~legoh_rl.training.workers.EnvSlice`,
    whose batches are ``[N, T]`` on ``device``.

    Args:
        cfg: the run's env config (``N = cfg.num_envs`` worlds); each worker builds its slice of
            ``N / workers`` worlds on the CPU with ``options.num_cpus_per_worker`` physics threads.
        workers: K, a divisor of ``N`` (:func:`~legoh_rl.training.workers.check_workers`).
        wrap: the recipe's env transforms (:attr:`Trainer.env_wrap`), or ``None``.
        policy: the trained behaviour policy; the workers get a CPU copy and its weights every
            :meth:`~RayWorkerCollector.update_policy_weights_` (sent once here, before any batch).
        frames_per_batch: ``N x T`` in all (``N/K x T`` from each worker).
        total_frames: frames to collect before the iterator stops.
        options: the ``collector.ray`` section (:func:`ray_options`).
        device: where the batches go (the run's ``device``).
        exploration_type: how the workers' policy acts (sampling: ``RANDOM``).
        **kwargs: the remote collectors' other keyword arguments (the trainer's ``collector_kwargs``).

    Raises:
        ImportError: Ray is not installed (names the install command).
        RuntimeError: the Ray cluster has fewer CPUs (or less memory) than the K workers reserve:
            they could never all start (names the numbers and the settings to change).
    """
    ray = import_ray()
    owns_ray = not ray.is_initialized()
    if owns_ray:
        _init_ray(ray, options)
    try:
        _check_room(ray, workers, options)
        threads = options.num_cpus_per_worker
        # slice_config gives worker k num_threads / workers physics threads: num_cpus_per_worker
        cfg = dataclasses.replace(cfg, device="cpu", num_threads=threads * workers)
        envs = [EnvSlice(cfg, k, workers, wrap) for k in range(workers)]
        shipped = policy
        if torch.device(device).type != "cpu":  # the policy (and a wrap holding modules) on the GPU
            envs, shipped = _on_cpu(envs), _on_cpu(policy)
        collector = RayWorkerCollector(
            envs, shipped, trained=policy, owns_ray=owns_ray, frames_per_batch=frames_per_batch,
            total_frames=total_frames, device="cpu", collector_class=WorkerCollector, sync=True,
            remote_configs=options.remote_config(), collector_kwargs=[dict(kwargs) for _ in range(workers)],
            postproc=_Batches(device), exploration_type=exploration_type)
    except BaseException:  # RayWorkerCollector stops what it started; this stops Ray when it never began
        if owns_ray and ray.is_initialized():
            ray.shutdown()
        raise
    try:
        collector.update_policy_weights_()  # connects the weight sync before the first batch
    except BaseException:
        collector.shutdown()
        raise
    return collector


def _init_ray(ray, options: RayOptions) -> None:
    """``ray.init`` that leaves this process's SIGTERM handler as it was: ``ray.init`` installs its
    own (exit at once, after killing a local instance's processes), which would end the run
    without the checkpoint the runner's :class:`~legoh_rl.training.interrupt.GracefulStop` writes."""
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main else None
    ray.init(**options.init_config())
    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


def _check_room(ray, workers: int, options: RayOptions) -> None:
    """Refuse a cluster too small for the K workers' reservations (Ray would wait for ever)."""
    total = ray.cluster_resources()
    cpus = workers * options.num_cpus_per_worker
    if total.get("CPU", 0) < cpus:
        raise RuntimeError(
            f"the Ray cluster has {total.get('CPU', 0):g} CPUs, collector.workers={workers} x "
            f"collector.ray.num_cpus_per_worker={options.num_cpus_per_worker} need {cpus}: "
            "use fewer workers or CPUs each, or add nodes (ray start --address=...)")
    if options.memory_per_worker_gib is not None:
        need = workers * options.memory_per_worker_gib * 2**30
        if total.get("memory", 0) < need:
            raise RuntimeError(
                f"the Ray cluster has {total.get('memory', 0) / 2**30:.1f} GiB for tasks, collector.workers={workers} x "
                f"collector.ray.memory_per_worker_gib={options.memory_per_worker_gib} need {need / 2**30:.1f}: "
                "lower collector.ray.memory_per_worker_gib (null: no reservation) or add nodes")
