"""``spinemocap demo``: the whole pipeline on a small synthetic capture, printing where everything
went.

The demo is a list of steps (:data:`STEPS`). Each step is a function ``step(ctx) -> None`` that
reads what earlier steps left in the :class:`DemoContext` (``ctx.out``, ``ctx.capture_dir``,
``ctx.results``...), does one thing, and reports its outputs with ``ctx.report(label, path)``.
To add a stage (tracking, export, report), write a step function below and append it to STEPS.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable


@dataclass
class DemoContext:
    """Shared state of the demo steps. ``outputs``: (label, path) in the order produced."""

    out: Path
    quick: bool = False
    capture_dir: Path | None = None
    results: dict = field(default_factory=dict)
    outputs: list[tuple[str, Path]] = field(default_factory=list)

    def synthesized(self) -> Path:
        """The capture the synthesize step wrote; RuntimeError before it ran."""
        if self.capture_dir is None:
            raise RuntimeError("the demo's synthesize step has not run")
        return self.capture_dir

    def report(self, label: str, path: Path) -> None:
        self.outputs.append((label, Path(path)))
        print(f"    {label:<28} {path}")


# ---------------------------------------------------------------------- steps
def step_synthesize(ctx: DemoContext) -> None:
    """Render a small synthetic capture (tape on an anny body, 4 cameras, light occlusion)."""
    from spinemocap.synth import SynthConfig, write_capture

    frames = 4 if ctx.quick else 12
    # 25 fps so the few frames span half a second of the motion (the report shows the spine moving)
    config = SynthConfig.preset("artificial", frames=frames, fps=25.0, size=(640, 480), rows=9,
                                occlusion="light", name="demo")
    ctx.capture_dir = write_capture(config, ctx.out / "capture", progress=True)
    ctx.report("capture (tracker input)", ctx.capture_dir / "capture.toml")
    ctx.report("camera rig", ctx.capture_dir / "rig.toml")
    ctx.report("images", ctx.capture_dir / "images")
    ctx.report("tape masks", ctx.capture_dir / "masks")
    ctx.report("ground truth", ctx.capture_dir / "groundtruth.npz")


def step_track(ctx: DemoContext) -> None:
    """Track the tape dots (LP + MRFs, sequence mode) and compare with the ground truth."""
    from spinemocap.app.run import track_capture
    from spinemocap.commands.track import accuracy_summary

    detector = "net"  # the shipped tape segmentation network
    out = ctx.out / "tracked"
    table = track_capture(ctx.synthesized(), out, mode="sequence", detector=detector)
    print(f"    detector {detector}; " + accuracy_summary(table, ctx.synthesized()))
    ctx.report("tracked markers (table)", out / "markers.csv")
    ctx.report("tracked markers (OpenSim)", out / "markers.trc")
    ctx.report("tracked markers (C3D)", out / "markers.c3d")


def step_view(ctx: DemoContext) -> None:
    """Labelled camera videos (MP4) and the tracked tape in 3D (HTML), linked from the report."""
    from spinemocap.app.batch import discover, trial_out_dir
    from spinemocap.app.viewer.layout import VIEWER_NAME, view_folder
    from spinemocap.app.viewer.scene3d import write_viewer
    from spinemocap.app.viewer.video import write_videos

    assert ctx.capture_dir is not None, "the capture is made first"
    tracked = ctx.out / "tracked"
    (trial,) = discover(ctx.capture_dir)
    out = view_folder(trial_out_dir(ctx.out / "report", trial))  # the report's trial folder: it links them
    videos = write_videos(ctx.capture_dir, tracked, out)
    print(f"    labelled videos: {len(videos.frames)} frames, {videos.frames_per_s:.1f} frames/s (all cameras)")
    for camera, path in videos.cameras.items():
        ctx.report(f"labelled video {camera}", path)
    if videos.grid is not None:
        ctx.report("labelled video, all cameras", videos.grid)
    ctx.report("tape in 3D (open in a browser)", write_viewer(ctx.capture_dir, tracked, out / VIEWER_NAME))


def step_report(ctx: DemoContext) -> None:
    """Spine angles and their report (HTML with plots, CSV, XLSX) for the capture."""
    from spinemocap.app.report import report_capture

    tracked = next((p for _, p in reversed(ctx.outputs) if p.name == "markers.csv"), None)
    paths = report_capture(ctx.synthesized(), ctx.out / "report", markers_csv=tracked)
    ctx.report("angle report", paths["html"])
    ctx.report("angle tables", paths["xlsx"])


STEPS: list[Callable[[DemoContext], None]] = [
    step_synthesize,
    step_track,
    step_view,
    step_report,  # last: reports on the markers of the steps before
]


# ---------------------------------------------------------------------- command
def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help="run the pipeline on a small synthetic capture and show the outputs")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default demo_out)")
    p.add_argument("--quick", action="store_true", help="fewer frames (for tests)")
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    ctx = DemoContext(out=args.out, quick=args.quick)
    ctx.out.mkdir(parents=True, exist_ok=True)
    for k, step in enumerate(STEPS, 1):
        title = (step.__doc__ or step.__name__).strip().splitlines()[0]
        print(f"[{k}/{len(STEPS)}] {title}")
        start = time.perf_counter()
        step(ctx)
        print(f"    done in {time.perf_counter() - start:.1f} s")
    print(f"\nAll demo outputs are under {ctx.out.resolve()}")
    return 0
