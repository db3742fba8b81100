"""Training throughput of each stage with Mitsuba vs LTC rendering: the cost of physically based
rendering during training.

    .venv/bin/python benchmarks/training_speed.py                 # small configs, this CPU
    python3 benchmarks/training_speed.py --full --device cuda     # full configs on a GPU

Each stage's config (train/<stage>-small.toml, or train/<stage>.toml with --full) runs
``--steps`` steps after one warm-up step (kernel compilation) with ``render.method`` set to
``mitsuba`` and to ``ltc``; pretrained networks come from the runs of the previous stages when they
exist, else from a fresh export of the stage's own untrained networks (the speed is the same).
Writes docs/benchmarks/training_speed_<device>.md (+ CSV).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

from mitsvbrdf.nets import network_record
from mitsvbrdf.training import STAGES, Trainer, load_config
from mitsvbrdf.training.stages import RenderSettings
from report import write_report

ROOT = Path(__file__).resolve().parent.parent


def pretrained_file(stage: str, tmp: Path, rig) -> Path:
    """Networks of a stage with fresh weights, for stages whose predecessors have not been run."""
    S = STAGES[stage]
    recs = {n: network_record(m) for n, m in S(S.Model(), S.Loss(), RenderSettings(), rig).networks().items()}
    path = tmp / f"{stage}-fresh.pt"
    torch.save(recs, path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--methods", default="mitsuba,ltc,ltc-prefiltered")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks")
    args = ap.parse_args()
    import mitsvbrdf as ms

    rig = ms.Rig.from_scene()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for stage in ("init", "stage1", "stage2", "finetune"):
            path = ROOT / "train" / (f"{stage}.toml" if args.full else f"{stage}-small.toml")
            for method in args.methods.split(","):
                render_opts = ["render.method=ltc", "render.ltc_mode=prefiltered"] if method == "ltc-prefiltered" \
                    else [f"render.method={method}"]
                cfg = load_config(path, render_opts + [ f"train.steps={args.steps + 1}",
                                         f"train.device={args.device}", f"out=\"{tmp / stage / method}\"",
                                         f"train.checkpoint_every={10 ** 9}"])
                prev = {"stage1": "init", "stage2": "stage1", "finetune": "stage2"}.get(stage)
                if prev and not Path(cfg.pretrained.networks).exists():
                    cfg.pretrained.networks = str(pretrained_file(stage, tmp, rig))
                trainer = Trainer(cfg, progress=False, stop_after=1)
                trainer.run()  # warm-up: kernels compile, caches fill
                trainer.stop_after = None
                if args.device == "cuda":
                    torch.cuda.synchronize()
                t0 = time.perf_counter()
                trainer.run()
                if args.device == "cuda":
                    torch.cuda.synchronize()
                dt = time.perf_counter() - t0
                row = {"stage": stage, "render": method, "size": cfg.data.size, "batch": cfg.train.batch,
                       "spp": cfg.render.spp if method == "mitsuba" else "-", "it_per_s": round(args.steps / dt, 3)}
                rows.append(row)
                print(row, flush=True)
    dev = args.device if args.device == "cpu" else torch.cuda.get_device_name()
    text = (f"Training steps per second on {dev} ({torch.get_num_threads()} threads), "
            f"{'full' if args.full else 'small'} configs, mean of {args.steps} steps after one warm-up step.\n\n"
            "| stage | render | px | batch | spp | it/s |\n|---|---|---:|---:|---:|---:|\n" +
            "\n".join(f"| {r['stage']} | {r['render']} | {r['size']} | {r['batch']} | {r['spp']} | {r['it_per_s']} |"
                      for r in rows) + "\n")
    print(text)
    write_report(args.out, f"training_speed_{args.device}{'_full' if args.full else ''}", "Training throughput",
                 "training_speed.py", text, rows)


if __name__ == "__main__":
    main()
