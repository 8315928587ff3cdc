"""Time of a 2-thread torch update under OpenMP's two wait policies, cores idle and one core busy.

    python benchmarks/openmp_wait.py [--steps 40]

Each setting runs in a fresh process (OpenMP reads ``OMP_WAIT_POLICY`` when torch loads): an
Adam step of a [256, 128, 64] MLP (the oracle's) on 1,536 samples, ms per step. "one busy" runs
a pure-Python busy loop in another process meanwhile, standing in for physics threads or a
second run. Compare the rows of one run: the machine's load drifts (``legoh_rl/openmp.py``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

CHILD = """
import sys, time, torch
torch.set_num_threads(int(sys.argv[1]))
torch.manual_seed(0)
net = torch.nn.Sequential(torch.nn.Linear(300, 256), torch.nn.ELU(), torch.nn.Linear(256, 128), torch.nn.ELU(),
                          torch.nn.Linear(128, 64), torch.nn.ELU(), torch.nn.Linear(64, 10))
opt = torch.optim.Adam(net.parameters())
x = torch.randn(1536, 300)
def step():
    opt.zero_grad(); net(x).pow(2).mean().backward(); opt.step()
for _ in range(5):
    step()
start = time.perf_counter()
for _ in range(int(sys.argv[2])):
    step()
print((time.perf_counter() - start) / int(sys.argv[2]) * 1000)
"""

BUSY = "while True: pass"


def timed(threads: int, policy: str | None, steps: int) -> float:
    """ms per update step in a fresh process with ``threads`` torch threads and ``policy``."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if policy is not None:
        env["OMP_WAIT_POLICY"] = policy
    out = subprocess.run([sys.executable, "-c", CHILD, str(threads), str(steps)], env=env, check=True,
                         capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=40, help="timed update steps per setting")
    args = p.parse_args()
    if args.steps < 1:
        p.error(f"--steps must be positive, got {args.steps}")
    settings = [("1 thread", 1, None), ("2 threads, spinning (OpenMP's default)", 2, None),
                ("2 threads, PASSIVE", 2, "PASSIVE")]
    results = {name: {} for name, *_ in settings}
    for load in ("idle", "one busy"):
        busy = subprocess.Popen([sys.executable, "-c", BUSY]) if load == "one busy" else None
        try:
            time.sleep(0.5 if busy else 0.0)
            for name, threads, policy in settings:
                results[name][load] = timed(threads, policy, args.steps)
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()
    print(f"\n{os.cpu_count()} CPUs; ms per update step\n")
    print("| policy | cores idle | one core busy |")
    print("|---|---:|---:|")
    for name, row in results.items():
        print(f"| {name} | {row['idle']:.1f} | {row['one busy']:.1f} |")


if __name__ == "__main__":
    main()
