"""``vslam vocab``: train, inspect and convert bag-of-words vocabularies."""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from vslam.errors import ConfigError

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "vocab", help="train / inspect / convert ORB bag-of-words vocabularies (DBoW2)",
        description="Bag-of-binary-words vocabularies for place recognition (Galvez-Lopez & Tardos 2012).",
    )
    vsub = p.add_subparsers(dest="vocab_command", metavar="ACTION")

    t = vsub.add_parser(
        "train", help="train a vocabulary from images or datasets",
        description="Extract ORB features (1000 per image) from every N-th frame of SOURCES and train a "
                    "k-majority vocabulary tree with TF-IDF weights. SOURCES are dataset folders "
                    "(TUM, KITTI, EuRoC, 7-Scenes), image folders (searched recursively) or image files. "
                    "Use the source 'default' for the built-in scikit-image training set.",
    )
    t.add_argument("sources", nargs="+", metavar="SOURCE", help="dataset / image folders, image files, or 'default'")
    t.add_argument("--output", "-o", required=True, help="output file (.npz, or .txt for DBoW2 text)")
    t.add_argument("--k", type=int, default=10, help="branching factor (default 10)")
    t.add_argument("--levels", "-L", type=int, default=5, help="depth L (default 5)")
    t.add_argument("--every", type=int, default=5, help="use every N-th frame (default 5)")
    t.add_argument("--max-frames", type=int, help="at most this many frames in total")
    t.add_argument("--features", type=int, default=1000, help="ORB features per image (default 1000)")
    t.add_argument("--iterations", type=int, default=10, help="k-majority iterations per node (default 10)")
    t.add_argument("--seed", type=int, default=0, help="k-means++ seed (default 0)")
    t.add_argument("--no-progress", action="store_true", help="no progress bars")
    t.add_argument("--format", choices=["npz", "dbow2-txt"], help="output format (default: from the extension)")
    t.set_defaults(func=run_train)

    i = vsub.add_parser("info", help="print a vocabulary's shape and load time")
    i.add_argument("vocabulary", nargs="?", help="vocabulary file (default: the packaged one)")
    i.set_defaults(func=run_info)

    c = vsub.add_parser("convert", help="convert between .npz and DBoW2 text (ORBvoc.txt)")
    c.add_argument("input", help="vocabulary file (.npz or DBoW2 .txt)")
    c.add_argument("output", help="output file (.npz or .txt)")
    c.set_defaults(func=run_convert)

    p.set_defaults(func=lambda args: (p.print_help(), 1)[1])
    return p


def _save(voc, output: str, fmt: str | None) -> Path:
    fmt = fmt or ("dbow2-txt" if output.endswith(".txt") else "npz")
    if fmt == "dbow2-txt":
        return voc.save_dbow2_text(output)
    return voc.save(output)


def _refuse_sources(output: str, sources: list[str]) -> None:
    """The vocabulary never lands on a source: an image given, or an image, list or calibration file
    in a source folder (which the readers would take as part of the sequence)."""
    from vslam.outputs import IMAGE_SUFFIXES, check_output_file, lies_inside, refuse_inputs

    refuse_inputs(output, [s for s in sources if s != "default"], "vocabulary")
    check_output_file(output, "vocabulary")
    out = Path(output)
    for src in sources:
        if src != "default" and Path(src).is_dir() and lies_inside(out, src) and (
                out.suffix.lower() in IMAGE_SUFFIXES
                or (out.exists() and out.suffix.lower() in (".txt", ".csv", ".yaml", ".yml"))):
            raise ConfigError(f"{output}: lies in the source folder {src} and may be one of its images or lists; "
                              "write the vocabulary elsewhere")


def run_train(args: argparse.Namespace) -> int:
    from vslam.api import progress_bar
    from vslam.loop.config import VocabularyConfig
    from vslam.loop.training import default_training_descriptors, descriptors_from_sources
    from vslam.loop.vocabulary import Vocabulary

    config = VocabularyConfig(k=args.k, levels=args.levels, max_iterations=args.iterations, seed=args.seed,
                              direct_index_level=min(2, args.levels))
    if args.every < 1 or args.features < 1:
        raise ConfigError("--every and --features must be >= 1")
    _refuse_sources(args.output, args.sources)
    t0 = time.perf_counter()
    sets = []
    real = [s for s in args.sources if s != "default"]
    if len(real) < len(args.sources):
        sets += default_training_descriptors(n_features=args.features)
    if real:
        sets += descriptors_from_sources(real, every=args.every, max_frames=args.max_frames, n_features=args.features,
                                         progress=progress_bar(not args.no_progress))
    n_desc = sum(len(s) for s in sets)
    print(f"{len(sets)} images, {n_desc} ORB descriptors ({time.perf_counter() - t0:.1f} s)")
    t1 = time.perf_counter()
    voc = Vocabulary.train(sets, config, progress=progress_bar(not args.no_progress))
    path = _save(voc, args.output, args.format)
    print(f"trained {voc} in {time.perf_counter() - t1:.1f} s -> {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from vslam.loop.vocabulary import DEFAULT_VOCABULARY_PATH, Vocabulary

    path = Path(args.vocabulary) if args.vocabulary else DEFAULT_VOCABULARY_PATH
    t0 = time.perf_counter()
    voc = Vocabulary.load(path)
    dt = time.perf_counter() - t0
    print(f"{path}: {voc}, loaded in {dt * 1000:.0f} ms, {path.stat().st_size / 1024:.0f} KiB")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from vslam.loop.vocabulary import Vocabulary
    from vslam.outputs import check_output_file, refuse_inputs

    refuse_inputs(args.output, (args.input,), "converted vocabulary")
    check_output_file(args.output, "vocabulary")
    voc = Vocabulary.load(args.input)
    path = _save(voc, args.output, None)
    print(f"{voc} -> {path}")
    return 0
