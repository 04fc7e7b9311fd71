"""A small synthetic study, analysed and reported: 3 subjects x 2 conditions x 2 trials.

    .venv/bin/python examples/synthetic_study.py --out study_out [--source tracked]

1. The synthetic studio (tiny preset: 3 cameras, small images) renders 12 captures of anny
   bodies of three phenotypes (the subjects) doing two movements (the conditions: slow forward
   flexion to full flexion, and a tennis forehand), two trials each with different seeds. The
   tape is laid from S1 as a taut strip over the gluteal cleft, with the studio's default row
   count (two rows past T12/L1 on every body), so the lumbar angle is the standard
   S1 -> T12/L1. The studio's default realism applies (Schober skin strain, exact set-up).
   Existing captures are kept.
2. ``run_batch`` computes the spine angles of every trial, on the studio's ground-truth markers
   by default (``--source tracked`` runs the tracker first), on a local process pool.
3. ``write_report`` writes study_out/results/report.html plus CSV/XLSX tables: ROM by subject
   and condition (box plots), lumbar motion from neutral (each trial's first frame), and per
   trial a picture of the spine at neutral / peak flexion / peak extension and the segmental
   flexion.

Same as the command line: ``spinemocap batch study_out/study --out study_out/results --source
groundtruth --lumbar S1 T12/L1 --report``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from spinemocap.analysis.angles import AngleSettings
from spinemocap.app.batch import run_batch
from spinemocap.app.report import write_report
from spinemocap.synth import SynthConfig, write_capture

SUBJECTS = {  # anny phenotypes in [0, 1]
    "S01": {"gender": 0.1, "height": 0.35, "weight": 0.4},
    "S02": {"gender": 0.9, "height": 0.7, "muscle": 0.7},
    "S03": {"gender": 0.5, "weight": 0.7, "age": 0.6},
}
CONDITIONS = {"flexion": "flexion", "forehand": "forehand"}  # condition -> studio motion
TRIALS = 2
TAPE_START = "S1"  # vertebral level of the tape's first row and the lumbar angle's lower end (S1 -> T12/L1)


def make_study(root: Path, frames: int, fps: float) -> None:
    for s, (subject, phenotype) in enumerate(SUBJECTS.items()):
        for condition, motion in CONDITIONS.items():
            for trial in range(1, TRIALS + 1):
                folder = root / subject / condition / f"trial{trial:02d}"
                if (folder / "capture.toml").is_file():
                    continue
                print(f"synthesizing {folder}")
                config = SynthConfig.preset("tiny", motion=motion, frames=frames, fps=fps,
                                            tape_start=TAPE_START, phenotype=phenotype, seed=10 * s + trial,
                                            name=f"{subject}-{condition}-{trial}")
                write_capture(config, folder, progress=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("study_out"))
    parser.add_argument("--frames", type=int, default=15, help="frames per trial (default 15)")
    parser.add_argument("--fps", type=float, default=5.0, help="frame rate (default 5: 3 s per trial)")
    parser.add_argument("--source", choices=("groundtruth", "tracked"), default="groundtruth")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    make_study(args.out / "study", args.frames, args.fps)
    result = run_batch(args.out / "study", args.out / "results", source=args.source, workers=args.workers,
                       settings=AngleSettings(lower=TAPE_START, thoracolumbar="T12/L1"))
    for trial in result.failed:
        print(f"FAILED {trial.summary.key}: {trial.summary.reason}")
    paths = write_report(args.out / "results", title="Synthetic study: lumbar angles")
    print(f"report: {paths['html']}\ntables: {paths['csv']}, {paths['xlsx']}")


if __name__ == "__main__":
    main()
