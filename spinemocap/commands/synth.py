"""``spinemocap synth OUT``: render a synthetic capture with exact ground truth;
``spinemocap bench render``: render speed (against the reference renderer) and the occlusion table."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)

# spinemocap.synth.appearance's vocabularies (spelt out here: the CLI starts without numpy and OpenCV)
TAPE_COLOUR_NAMES = ("black", "beige", "blue", "pink", "red")
BACKDROP_NAMES = ("plain", "room")
CAMERA_LOOK_NAMES = ("ideal", "lab")
TAPE_ROLL_NAMES = ("standard", "small_holes", "large_holes", "close_rows", "wide_rows")
TAPE_FINISH_NAMES = ("smooth", "weave", "printed")
SKIN_MARK_NAMES = ("hair", "freckles", "moles", "sweat", "tattoo")
CLOTHING_NAMES = ("shorts", "bra_strap")
CODEC_NAMES = ("none", "jpeg", "h264", "h265")
JOINT_DEPTH_NAMES = ("anny", "anatomical")  # spinemocap.synth.body.JOINT_DEPTHS


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 1024x768, got {text!r}") from None


def _numbers(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, one per camera, got {text!r}") from None


def _names(vocabulary: tuple[str, ...]):
    """An argparse type: comma-separated names of ``vocabulary`` (empty: none)."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(n.strip() for n in text.split(",") if n.strip())
        unknown = [n for n in names if n not in vocabulary]
        if unknown:
            raise argparse.ArgumentTypeError(f"unknown {', '.join(unknown)}; choose any of {', '.join(vocabulary)}")
        return names
    return parse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "synth", help="render a synthetic tape capture (anny body, cameras, occluders) with ground truth",
        description="Render a synthetic capture folder OUT (capture.toml, rig.toml, images or videos, "
                    "tape masks, groundtruth.npz) that the tracker reads like a real one. A preset "
                    "sets every value; the flags override single ones.")
    p.add_argument("out", type=Path, help="output capture folder")
    p.add_argument("--preset", default="tiny", choices=("tiny", "artificial", "studio"),
                   help="tiny: 3 small cameras, 4 frames (tests); artificial: the paper's Artificial "
                        "experiment (4 cameras, 13 rows, 548 frames at 100 fps); studio: 6 cameras on a "
                        "180 degree arc, 2448x1600, 100 fps")
    p.add_argument("--frames", type=int, help="number of frames")
    p.add_argument("--fps", type=float, help="frame rate (Hz)")
    p.add_argument("--cameras", type=int, help="number of cameras (spread over the preset's arc)")
    p.add_argument("--size", type=_size, help="image size WxH in pixels")
    p.add_argument("--rows", type=int, help="tape rows (odd: 2-3-2-...-2 dots); default: the preset's (13 for artificial "
                                            "and studio), else enough to pass T12/L1 by two rows on this body")
    p.add_argument("--motion", help="flexion (to full forward flexion, 70 deg of spine), lateral, rotation, mixed, "
                                    "forehand (fast swing at 0.35-0.5 s) or neutral")
    p.add_argument("--occlusion", choices=("none", "light", "heavy"),
                   help="falling balls: light/heavy = the paper's 5000/10000 balls per 548 frames")
    p.add_argument("--balls", type=int, help="number of falling balls over the whole sequence (overrides --occlusion)")
    p.add_argument("--band", action="store_true", help="add a sports-bra band around the chest")
    p.add_argument("--band-level", help="vertebral level the band is centred on (default T9)")
    p.add_argument("--tape-start", help="vertebral level of the tape's first row, S2..T1 (default S1); the tape is laid "
                                        "as a taut strip that bridges the gluteal cleft and the spinal groove")
    p.add_argument("--realism", choices=("ideal", "skin", "lab"), default="lab",
                   help="how hard the studio is (default lab): lab = 15 %% taping tension, Schober skin strain, 0.5 px "
                        "calibration error, 1 ms sync error, sensor noise 3; skin = skin strain only, exact set-up "
                        "(the Python API's default); ideal = no strain, exact set-up. The flags "
                        "below override single values")
    p.add_argument("--skin-strain", type=float, metavar="SCALE",
                   help="scale of the Schober skin strain (0 = off, 1 = a healthy adult: the lumbar skin "
                        "lengthens by about a third at full flexion)")
    p.add_argument("--tape-tension", type=float, metavar="FRACTION",
                   help="the tape was laid stretched by this fraction along its length (0.2 = dots 20 %% farther "
                        "apart on the skin than the roll's spec; uneven along the tape by a seeded few percent); "
                        "capture.toml keeps the roll's spec, groundtruth.npz the true layout")
    p.add_argument("--calibration-error", type=float, metavar="PX",
                   help="write a rig.toml perturbed (rotations, centres, focal lengths) so that the true dots "
                        "reproject with this RMS per camera; the images stay exact, groundtruth.npz keeps the true rig")
    p.add_argument("--sync-error", type=float, metavar="MS",
                   help="per-camera clock offsets with this RMS (ms): each camera renders at its own offset times "
                        "(a residual error of synchronised cameras; for cameras that are not synchronised at all see "
                        "--camera-offsets)")
    p.add_argument("--camera-offsets", type=_numbers, metavar="S,S,...",
                   help="cameras that are not synchronised: each camera's clock minus the capture's, seconds, one per "
                        "camera (whole or fractional frames, up to +-5 s): each records on its own clock from capture "
                        "time -offset to the capture's end (truth in groundtruth.npz clock_offsets_s)")
    p.add_argument("--camera-fps", type=_numbers, metavar="FPS,FPS,...",
                   help="each camera's own frame rate (e.g. 50,60,100,100); capture.toml names them ([camera.NAME] fps)")
    p.add_argument("--drop-frames", type=int, metavar="N",
                   help="N frames missing from the videos (seeded cameras and places; gaps in their timestamps; "
                        "needs --video)")
    p.add_argument("--clap", action="store_true",
                   help="the videos carry an audio track with a hand clap every camera hears (needs --video)")
    p.add_argument("--reference", action="store_true",
                   help="an L-frame of five markers on a stand beside the subject, in view of the cameras (artificial "
                        "and studio layouts): rendered in the images, its design and pose in reference.toml (named by "
                        "capture.toml), for spinemocap track --refine-rig to fix the world frame with")
    p.add_argument("--blur", type=float, help="motion blur: exposure as a fraction of the frame interval (0..1)")
    p.add_argument("--noise", type=float, help="sensor noise, standard deviation in grey levels")
    p.add_argument("--distortion", type=float, help="lens distortion scale (0 = ideal pinhole, 1 = mild)")
    p.add_argument("--skin-tone", type=float, help="0 (light) .. 1 (dark); default from the seed")
    p.add_argument("--tape-colour", choices=TAPE_COLOUR_NAMES, help="the tape's colour (default black)")
    p.add_argument("--backdrop", choices=BACKDROP_NAMES,
                   help="behind the subject: plain (default) or a painted motion-capture room (windows, blinds, "
                        "wall bars, treadmill, posters, lights, camera strobes), one view per camera")
    p.add_argument("--bystanders", type=int,
                   help="other people standing in the painted room (with --backdrop room; default 0): skin, hair "
                        "and clothing that are not the subject's")
    p.add_argument("--camera-look", choices=CAMERA_LOOK_NAMES,
                   help="light and camera: ideal (default) or lab (per camera a seeded mix of lamp colour, mains "
                        "flicker, auto-exposure, defocus, 4:2:0 chroma, JPEG, H.264 or H.265 at sports-camera bitrates, "
                        "rolling shutters)")
    p.add_argument("--tape-roll", choices=TAPE_ROLL_NAMES,
                   help="the perforated roll: standard (10 mm holes, rows 25 mm apart, columns 15 mm; default), "
                        "small_holes (7 mm), large_holes (12 mm), close_rows (20 mm rows, 14 mm columns) or wide_rows "
                        "(30 mm rows, 16 mm columns); capture.toml gives the tracker the roll's layout")
    p.add_argument("--joint-depth", choices=JOINT_DEPTH_NAMES,
                   help="where the spine bends under the skin: anny (the body model's joints, 28-40 mm under the back; "
                        "default) or anatomical (moved to the published depth of the vertebral bodies, 53-76 mm, so that "
                        "the skin's slide over the vertebrae in flexion takes a real back's share)")
    p.add_argument("--tape-finish", choices=TAPE_FINISH_NAMES,
                   help="the tape's surface: smooth (default), weave (cotton weave) or printed (stripes, camouflage or "
                        "lettering in a contrasting ink)")
    p.add_argument("--skin-marks", type=_names(SKIN_MARK_NAMES), metavar="MARK,...",
                   help="marks on the subject's skin, any of hair, freckles, moles, sweat (a sheen), tattoo; they lie "
                        "under the tape and show through its holes")
    p.add_argument("--clothing", type=_names(CLOTHING_NAMES), metavar="ITEM,...",
                   help="garments, any of shorts (waistband just below the tape) and bra_strap (a sports bra's back "
                        "band between T10 and T6); where they cross the tape they hide it in the images, masks and "
                        "ground-truth visibility")
    p.add_argument("--rolling-shutter", type=float, metavar="MS",
                   help="every camera's rolling-shutter readout, top row to bottom row (0 = global shutter; default: "
                        "the camera look's); groundtruth.npz uv holds where each dot was when its row was read")
    p.add_argument("--camera-codec", choices=CODEC_NAMES,
                   help="every camera's frames through this codec (default: the camera look's)")
    p.add_argument("--phenotype", action="append", default=[], metavar="KEY=VALUE",
                   help="anny phenotype value in [0, 1] (repeatable): gender (or sex; 0 male, 1 female), age "
                        "(0 newborn, 0.5 young adult, 1 old), muscle, weight, height, proportions")
    p.add_argument("--supersample", type=int, help="render at N x resolution and downsample (anti-aliasing)")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--video", action="store_true", help="write lossless videos instead of PNG images")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--vicon", action="store_true", help="also write vicon.c3d: a virtual Vicon (200 Hz, own frame and "
                   "clock, gaps where its camera ring loses sight of a marker; truth in groundtruth.npz), and a wand "
                   "wave (wand/: images + Vicon C3D) for 'spinemocap calibrate wand'")
    p.add_argument("--wand-seconds", type=float, default=4.0,
                   help="length of the --vicon wand wave at the capture's frame rate (default 4; 0 = none)")
    p.set_defaults(func=run_synth)


def config_from_args(args: argparse.Namespace):
    from spinemocap.fileio import InputError
    from spinemocap.synth import SynthConfig

    phenotype = {}
    for item in args.phenotype:
        key, sep, value = item.partition("=")
        try:
            phenotype[key.strip()] = float(value)
        except ValueError:
            raise InputError("--phenotype", f"expected KEY=VALUE with a number, got {item!r}") from None
        if not sep:
            raise InputError("--phenotype", f"expected KEY=VALUE, got {item!r}")
    overrides = {
        "frames": args.frames, "fps": args.fps, "cameras": args.cameras, "size": args.size, "rows": args.rows,
        "motion": args.motion, "occlusion": args.occlusion, "band": args.band or None, "band_level": args.band_level,
        "tape_start": args.tape_start, "realism": args.realism, "skin_strain": args.skin_strain, "tape_tension": args.tape_tension,
        "calibration_error_px": args.calibration_error, "sync_error_ms": args.sync_error, "blur": args.blur, "noise": args.noise, "distortion": args.distortion,
        "supersample": args.supersample, "seed": args.seed, "video": args.video or None,
        "reference": args.reference or None, "camera_offsets_s": args.camera_offsets, "camera_fps": args.camera_fps,
        "drop_frames": args.drop_frames, "clap": args.clap or None,
        "tape_colour": args.tape_colour, "backdrop": args.backdrop, "bystanders": args.bystanders,
        "camera_look": args.camera_look,
        "tape_roll": args.tape_roll, "tape_finish": args.tape_finish, "skin_marks": args.skin_marks,
        "clothing": args.clothing, "rolling_shutter_ms": args.rolling_shutter, "camera_codec": args.camera_codec,
        "phenotype": phenotype or None, "joint_depth": args.joint_depth, "name": args.out.name,
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if args.balls is not None:
        overrides["balls"] = args.balls
    if args.skin_tone is not None:
        overrides["skin_tone"] = args.skin_tone
    try:
        return SynthConfig.preset(args.preset, **overrides)
    except ValueError as exc:
        raise InputError("spinemocap synth", str(exc)) from exc


def run_synth(args: argparse.Namespace) -> int:
    from spinemocap.capture import Capture
    from spinemocap.fileio import InputError
    from spinemocap.synth import write_capture

    config = config_from_args(args)
    if args.wand_seconds < 0:
        raise InputError("--wand-seconds", f"must be positive (got {args.wand_seconds:g}); 0 turns the wand wave off")
    try:
        out = write_capture(config, args.out, progress=not args.no_progress)
    except ValueError as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError("spinemocap synth", str(exc)) from exc
    if args.vicon:  # virtual Vicon (spinemocap/app/virtual_vicon.py)
        from ..app.virtual_vicon import write_virtual_vicon

        write_virtual_vicon(config, out, wand_seconds=args.wand_seconds, progress=not args.no_progress)
        wand = out / "wand" / "README.txt"
        print(f"virtual Vicon: {out}/vicon.c3d" + (f"; wand wave in {out}/wand/ (commands in {wand})"
                                                    if wand.exists() else "; no wand wave (see the warning above)"))
    media = "videos/" if config.video else "images/"
    rows = Capture.open(out).tape.n_rows
    print(f"synthetic capture written to {out}/ ({config.frames} frames, {config.cameras} cameras, "
          f"{rows}-row tape from {config.tape_start}, {config.n_balls} balls): capture.toml, rig.toml, {media}, "
          + ("" if config.unsynchronised else "masks/, ") + "groundtruth.npz" + (", reference.toml (the L-frame beside the subject)" if config.reference else ""))
    print(f"realism {config.realism}: skin strain x{config.skin_strain:g}, tape tension {100 * config.tape_tension:g} %, "
          f"calibration error {config.calibration_error_px:g} px (rig.toml), sync error {config.sync_error_ms:g} ms, "
          f"sensor noise {config.noise:g}")
    return 0


# ---------------------------------------------------------------------- benchmark
def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render", help="synthetic studio: seconds per rendered and written frame (artificial and studio presets, "
                       "lab level) against the reference renderer in the same run, and the occlusion visibility "
                       "table against the paper's Table 2")
    p.add_argument("--frames", type=int, default=3, help="frames to time per preset and renderer (default 3)")
    p.add_argument("--presets", default="artificial,studio",
                   help="comma-separated presets to time (default artificial,studio)")
    p.add_argument("--realism", choices=("ideal", "skin", "lab"), default="lab",
                   help="realism level of the timed scenes (default lab)")
    p.add_argument("--occlusion", choices=("none", "light", "heavy"), default="none",
                   help="falling balls in the timed scenes (default none; the realism benchmark renders light)")
    p.add_argument("--rounds", type=int, default=2,
                   help="times the reference renderer and this one alternate; the fastest round of each counts (default 2)")
    p.add_argument("--visibility-frames", type=int, default=548,
                   help="frames of the artificial sequence for the visibility table (paper: 548; 0 skips it)")
    p.add_argument("--out", type=Path, default=Path("bench_out/render"), help="folder for the plot and numbers")
    p.set_defaults(func=run_bench_render)
    p = subparsers.add_parser(
        "studio", help="synthetic studio realism envelope: tape stretch against the spec (between rows, whole tape, "
                       "across), Schober growth, calibration and sync errors per realism level and motion")
    p.add_argument("--frames", type=int, default=60, help="frames per motion (default 60 at 20 fps: 3 s)")
    p.add_argument("--fps", type=float, default=20.0, help="frame rate (default 20)")
    p.add_argument("--out", type=Path, default=Path("bench_out/studio"), help="folder for the plot and numbers")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_bench_studio)


def run_bench_studio(args: argparse.Namespace) -> int:
    from spinemocap.bench.synth import run_studio_benchmark

    run_studio_benchmark(args.frames, args.fps, args.out, progress=not args.no_progress)
    return 0


def run_bench_render(args: argparse.Namespace) -> int:
    from spinemocap.bench.synth import run_render_benchmark
    from spinemocap.fileio import InputError
    from spinemocap.synth import SynthConfig

    presets = [name.strip() for name in args.presets.split(",") if name.strip()]
    if not presets or args.frames < 1 or args.rounds < 1:
        raise InputError("spinemocap bench render", "need at least one preset, --frames >= 1 and --rounds >= 1")
    for name in presets:
        try:
            SynthConfig.preset(name)
        except ValueError as exc:
            raise InputError("spinemocap bench render --presets", str(exc)) from exc
    run_render_benchmark(args.frames, args.visibility_frames, args.out, presets, args.realism, args.rounds,
                         args.occlusion)
    return 0
