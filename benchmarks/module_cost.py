"""Parameters, FLOPs and CPU latency of every network in ``legoh_rl.modules``.

For each perception network (``make_perception`` names) in the ``cpu`` and ``paper``
presets, and for the oracle actor / critic, the student locomotion actor and the
adaptation module, prints:

* params (millions);
* GFLOPs per sample at batch 1, counted by ``torch.utils.flop_counter.FlopCounterMode``
  (2 FLOPs per multiply-accumulate; CPU scaled-dot-product attention is added with the
  counter's own SDPA formula), and the same as GMACs (multiply-accumulates, the
  convention of fvcore/thop that most vision papers call "FLOPs");
* median (and minimum) CPU forward latency (eval, no grad) at batch 1 and 64 with
  ``torch.set_num_threads(--threads)``.

The paper reports TC-ViT at 0.686 G / 31.25M params (and 0.785 G / 55.92M with a causal
transformer instead of the GRU).

Usage::

    python benchmarks/module_cost.py                       # everything, 2 threads
    python benchmarks/module_cost.py --configs cpu --batches 1 --runs 50 --threads 1 2

Latencies on a shared machine are pessimistic: other processes compete for the cores.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from tensordict import TensorDict
from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count
from torchrl.envs.utils import ExplorationType, set_exploration_type

from legoh_rl.modules import (
    PERCEPTION_BUILDERS,
    AdaptationConfig,
    LocomotionConfig,
    OracleConfig,
    make_adaptation_module,
    make_locomotion_actor,
    make_oracle_actor_critic,
    make_perception,
    perception_config,
)

PAPER_TCVIT = {"gmacs": 0.686, "params_m": 31.25}
PAPER_TCVIT_CT = {"gmacs": 0.785, "params_m": 55.92}


def _cpu_sdpa_flops(query_shape, key_shape, value_shape, *args, out_shape=None, **kwargs):
    return sdpa_flop_count(query_shape, key_shape, value_shape)


FLOP_MAPPING = {
    torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: _cpu_sdpa_flops,
}


def perception_inputs(cfg, batch: int) -> TensorDict:
    """Random inputs (and zero recurrent state) for every perception network."""
    io = cfg.io
    h = io.image_size
    return TensorDict(
        {
            "depth_goal_stack": torch.rand(batch, io.num_frames, io.stack_channels, h, h),
            "depth": torch.rand(batch, 1, h, h),
            "goal_gps": torch.randn(batch, io.gps_dim),
            "waypoint_gps": torch.randn(batch, io.gps_dim),
            "proprio": torch.randn(batch, io.proprio_dim),
            "proprio_history": torch.randn(batch, io.history_len, io.proprio_dim),
            "is_init": torch.zeros(batch, 1, dtype=torch.bool),
        },
        batch_size=[batch],
    )


def policy_inputs(proprio_dim: int, num_actions: int, batch: int) -> TensorDict:
    """Random inputs of the oracle, the locomotion actor and the adaptation module."""
    return TensorDict(
        {
            "proprio": torch.randn(batch, proprio_dim),
            "scandots": torch.randn(batch, 132),
            "privileged": torch.randn(batch, 8 + num_actions),
            "expert_goals": torch.randn(batch, 3, 2),
            "proprio_history": torch.randn(batch, 10, proprio_dim),
            "z_uni": torch.randn(batch, 32),
            "delta_g0": torch.randn(batch, 2),
            "goal_next": torch.randn(batch, 2),
        },
        batch_size=[batch],
    )


def count_flops(module, td: TensorDict) -> int:
    """FLOPs of one forward of ``module`` on ``td`` (2 per multiply-accumulate)."""
    counter = FlopCounterMode(display=False, custom_mapping=FLOP_MAPPING)
    with torch.no_grad(), counter:
        module(td.clone())
    return counter.get_total_flops()


def latency_ms(module, td: TensorDict, runs: int, warmup: int = 3) -> tuple[float, float]:
    """(median, min) wall time of ``module(td)`` in milliseconds."""
    with torch.no_grad():
        for _ in range(warmup):
            module(td)
        times = []
        for _ in range(runs):
            start = time.perf_counter()
            module(td)
            times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times), 1e3 * min(times)


def measure(name: str, module, make_td, batches, runs: int) -> dict:
    module.eval()
    row = {"name": name, "params_m": sum(p.numel() for p in module.parameters()) / 1e6}
    flops = count_flops(module, make_td(1))
    row["gflops"] = flops / 1e9
    row["gmacs"] = flops / 2e9
    for b in batches:
        n = runs if b == 1 else max(3, runs // 5)
        row[f"ms@{b}"], row[f"min@{b}"] = latency_ms(module, make_td(b), n)
    return row


def header(batches) -> str:
    head = f"{'module':28s} {'params[M]':>10s} {'GFLOPs':>8s} {'GMACs':>8s}"
    head += "".join(f" {'ms@' + str(b):>9s} {'(min)':>8s}" for b in batches)
    return head + "\n" + "-" * len(head)


def format_row(r, batches) -> str:
    line = f"{r['name']:28s} {r['params_m']:10.3f} {r['gflops']:8.4f} {r['gmacs']:8.4f}"
    return line + "".join(f" {r[f'ms@{b}']:9.2f} {r[f'min@{b}']:8.2f}" for b in batches)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--configs", nargs="+", default=["cpu", "paper"], choices=["cpu", "paper"])
    parser.add_argument("--names", nargs="+", default=sorted(PERCEPTION_BUILDERS))
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 64])
    parser.add_argument("--threads", nargs="+", type=int, default=[2],
                        help="intra-op thread counts to time (one table each)")
    parser.add_argument("--runs", type=int, default=30, help="timed runs at batch 1")
    parser.add_argument("--num-actions", type=int, default=10)
    parser.add_argument("--no-policies", action="store_true", help="perception networks only")
    args = parser.parse_args()
    a = args.num_actions
    proprio_dim = 3 + 2 + 3 * a + 2
    print(f"torch {torch.__version__}, A={a}, proprio_dim={proprio_dim}")
    print(f"paper: TC-ViT {PAPER_TCVIT['gmacs']} G / {PAPER_TCVIT['params_m']}M params; "
          f"with CT {PAPER_TCVIT_CT['gmacs']} G / {PAPER_TCVIT_CT['params_m']}M")
    for threads in args.threads:
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        print(f"\n== torch.set_num_threads({threads}) ==")
        print(header(args.batches), flush=True)
        run_all(args, proprio_dim)


def run_all(args, proprio_dim: int) -> None:
    """Measure and print every module once."""
    a = args.num_actions
    for preset in args.configs:
        cfg = perception_config(preset, proprio_dim=proprio_dim)
        for name in args.names:
            row = measure(f"{name} [{preset} {cfg.io.image_size}px]", make_perception(name, cfg),
                          lambda b, cfg=cfg: perception_inputs(cfg, b), args.batches, args.runs)
            print(format_row(row, args.batches), flush=True)
    if args.no_policies:
        return
    oracle_cfg = OracleConfig(proprio_dim=proprio_dim, num_actions=a, privileged_dim=8 + a)
    actor, critic = make_oracle_actor_critic(oracle_cfg)
    loco = make_locomotion_actor(LocomotionConfig(proprio_dim=proprio_dim, num_actions=a))
    adapt = make_adaptation_module(AdaptationConfig(proprio_dim=proprio_dim))

    def pol(b):
        return policy_inputs(proprio_dim, a, b)

    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for name, module in [("oracle actor", actor), ("oracle critic", critic),
                             ("locomotion actor", loco), ("adaptation module", adapt)]:
            row = measure(name, module, pol, args.batches, args.runs)
            print(format_row(row, args.batches), flush=True)


if __name__ == "__main__":
    main()
