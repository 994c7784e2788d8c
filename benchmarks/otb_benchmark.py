"""SPTPT presets and OpenCV peers on every sequence of an OTB-layout root, in one invocation.

    python -m benchmarks.otb_benchmark                       # all trackers, ../shared/otb, records RESULTS.md
    python -m benchmarks.otb_benchmark --trackers paper,csrt --stop 100 --no-record
    python -m benchmarks.otb_benchmark --trackers paper,robust,csrt --seeds 0,1,2 --sequences Coke,David --no-record
    python -m benchmarks.otb_benchmark --variant 'flow=robust:flow_prior=true' --trackers robust,flow --no-record
    python -m benchmarks.otb_benchmark --replot /tmp/runs --trackers paper,robust,csrt   # attribute plots, no tracking

For each tracker it runs one-pass evaluation on the same frames (the
sequence's ``img/`` files, in order), then reports mean success AUC,
precision at 20 px and frames per second; for SPTPT also the per-stage
timing and peak resident memory (review flags are measured by
``benchmarks/failure_model.py``). The peers CSRT, KCF and MIL (from
opencv-contrib-python-headless) run in an environment of their own,
``benchmarks/_env``, created on first use, because that package clashes with
the project's opencv-python-headless; NanoTrack runs with the project's
OpenCV and the weights in ``../shared/anchors`` (a benchmark peer only).
``--variant`` runs a preset with changed parameters under a name of its own.

With ``--seeds`` every SPTPT preset runs once per seed and the report adds
the mean and standard deviation over seeds of the AUC per sequence and
overall; the peers have no seed and run once. Flags, stage timing and
plots use the first seed.

After the overall plots come per-attribute success plots: OTB-100's attribute
labels of these sequences are in ``benchmarks/otb_attributes.json``; each
attribute held by at least two of the benchmarked sequences gets
``otb_plots/attributes/<CODE>.png`` (each tracker's success curve as the
unweighted mean over those sequences, SPTPT presets also averaged over seeds)
and a column in a table of mean AUC per attribute. ``--replot OUT`` draws these
from the result files of an earlier run in OUT (its ``seed<N>/`` folders are
found by themselves) without tracking anything.

Frames per second are measured over frames 2..N (the first frame's
initialisation excluded) with one sequence at a time unless ``--workers`` is
raised, which makes the figures per-process under load and is meant for
tuning only.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import re
import subprocess
import sys
import time
import venv
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

from annotator.evaluation import DatasetScore, evaluate_dataset, write_report  # noqa: E402
from annotator.evaluation.report import plot_success  # noqa: E402
from annotator.otb_format import read_otb_boxes  # noqa: E402
from benchmarks._results import machine_line, update_section  # noqa: E402
from benchmarks._sequences import SequenceError, select_sequences  # noqa: E402
from sptpt.params import PRESETS  # noqa: E402
from sptpt.tracker import STAGES  # noqa: E402

PEERS = ("csrt", "kcf", "mil", "nanotrack")
MAIN_ENV_PEERS = ("nanotrack",)  # in OpenCV's main modules: no separate environment needed
PEER_ENV = HERE / "_env"
PEER_REQUIREMENTS = ["opencv-contrib-python-headless", "numpy"]
ATTRIBUTES_FILE = HERE / "otb_attributes.json"
MIN_ATTRIBUTE_SEQUENCES = 2  # an attribute held by fewer benchmarked sequences gets no plot


def ensure_peer_env() -> Path:
    """Create ``benchmarks/_env`` with OpenCV contrib once; return its python."""
    python = PEER_ENV / "bin" / "python"
    if not python.exists():
        print(f"creating {PEER_ENV} with {' '.join(PEER_REQUIREMENTS)} ...", file=sys.stderr)
        venv.EnvBuilder(with_pip=True, clear=True).create(PEER_ENV)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", *PEER_REQUIREMENTS], check=True)
    return python


def _sptpt_job(args: dict) -> dict:
    import numba

    threads = args.pop("numba_threads")
    if threads is not None:
        numba.set_num_threads(threads)
    from benchmarks._sptpt_runner import run_sequence

    return run_sequence(**args)


def _peer_job(args: dict) -> dict:
    python = args.pop("python")
    out = subprocess.run([python, str(HERE / "_peer_runner.py"), json.dumps(args)], check=True, capture_output=True,
                         text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def parse_variant(text: str) -> tuple[str, dict]:
    """``NAME=PRESET:key=value,key=value`` -> (NAME, the preset's parameters with the overrides)."""
    import yaml

    from sptpt.params import params_from_mapping

    name, _, spec = text.partition("=")
    preset, _, overrides = spec.partition(":")
    if not name or preset not in PRESETS:
        raise ValueError(f"--variant {text!r}: expected NAME=PRESET:key=value,... with PRESET one of {sorted(PRESETS)}")
    changes = {}
    # Commas inside [...] belong to a list value (motion_sigma=[0.15,0.15,0.02,0,0,0]).
    for item in filter(None, re.split(r",(?![^\[]*\])", overrides)):
        key, _, value = item.partition("=")
        changes[key] = yaml.safe_load(value)
    return name, params_from_mapping(changes, base=PRESETS[preset]).to_dict()


def run_tracker(name: str, sequences: list[Path], out_root: Path, *, workers: int, seed: int, stop: int | None,
                peer_python: Path | None, configs: dict[str, dict]) -> list[dict]:
    out_dir = out_root / name
    if name in PEERS:
        python = sys.executable if name in MAIN_ENV_PEERS else str(peer_python)
        jobs = [dict(python=python, tracker=name, seq_dir=str(s), out_dir=str(out_dir), name=s.name, stop=stop)
                for s in sequences]
        fn = _peer_job
    else:
        params = configs[name]
        jobs = [dict(seq_dir=str(s), out_dir=str(out_dir), params=params, seed=seed, name=s.name, stop=stop,
                     numba_threads=1 if workers > 1 else None) for s in sequences]
        fn = _sptpt_job
    if workers == 1:
        return [fn(job) for job in jobs]
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
        return list(pool.map(fn, jobs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--otb", type=Path, default=HERE.parent.parent / "shared" / "otb")
    parser.add_argument("--trackers", default="paper,fast,robust,csrt,kcf,mil,nanotrack")
    parser.add_argument("--sequences", default="", help="comma-separated names, or 'all' (the default: every sequence)")
    parser.add_argument("--stop", type=int, default=None, help="only the first N frames of each sequence")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default="", help="comma-separated seeds for the SPTPT presets (overrides --seed)")
    parser.add_argument("--out", type=Path, default=HERE / "_runs" / "otb")
    parser.add_argument("--no-record", action="store_true", help="do not update benchmarks/RESULTS.md")
    parser.add_argument("--variant", action="append", default=[],
                        help="NAME=PRESET:key=value,... a preset with changed parameters, run as tracker NAME "
                             "(development comparisons; repeatable)")
    parser.add_argument("--replot", type=Path, default=None, metavar="OUT",
                        help="track nothing: draw the per-attribute plots and table from the result files of an "
                             "earlier run in OUT (--trackers that have results there; seeds from --seeds or OUT's "
                             "seed<N>/ folders); plots go to otb_plots/attributes, or OUT/plots/attributes with "
                             "--no-record; RESULTS.md is not touched")
    args = parser.parse_args()

    try:
        sequences = sorted(select_sequences(args.otb, args.sequences))  # the tables list sequences by name
    except SequenceError as err:
        parser.error(str(err))
    trackers = [t for t in args.trackers.split(",") if t]
    if args.replot is not None:
        print(replot(args.replot, trackers, sequences, seeds=[int(v) for v in args.seeds.split(",") if v],
                     plot_dir=(args.replot / "plots" if args.no_record else HERE / "otb_plots") / "attributes"))
        return
    try:
        configs = {name: p.to_dict() for name, p in PRESETS.items()} | dict(map(parse_variant, args.variant))
    except ValueError as err:
        parser.error(str(err))
    unknown = [t for t in trackers if t not in PEERS and t not in configs]
    if unknown:
        parser.error(f"unknown trackers {unknown}: choose from {sorted(configs)} and {list(PEERS)}")
    peer_python = ensure_peer_env() if any(t in PEERS and t not in MAIN_ENV_PEERS for t in trackers) else None

    seeds = [int(v) for v in args.seeds.split(",") if v] if args.seeds else [args.seed]
    args.seed = seeds[0]
    records: dict[str, list[dict]] = {}
    started = time.time()
    for tracker in trackers:
        for k, seed in enumerate(seeds if tracker in configs else seeds[:1]):
            tic = time.time()
            recs = run_tracker(tracker, sequences, _seed_root(args.out, seeds, seed), workers=args.workers, seed=seed,
                               stop=args.stop, peer_python=peer_python, configs=configs)
            if k == 0:
                records[tracker] = recs
            print(f"{tracker} seed {seed}: {sum(r['frames'] for r in recs)} frames in {time.time() - tic:.0f} s",
                  file=sys.stderr)

    gts = {s.name: read_otb_boxes(s / "groundtruth_rect.txt") for s in sequences}
    per_seed = scores_per_seed(args.out, seeds, trackers, sequences, gts)
    seed_table = _seed_table(per_seed, seeds, trackers, sequences) if len(seeds) > 1 else None
    if len(seeds) > 1:
        args.out = _seed_root(args.out, seeds, seeds[0])
    scores, rows = [], []
    for tracker in trackers:
        score = per_seed[tracker][0]  # flags, stage timing and plots use the first seed
        scores.append(score)
        recs = records[tracker]
        fps = sum(r["frames"] - 1 for r in recs) / sum(r["seconds_after_first"] for r in recs)
        row = {"tracker": score.tracker, "auc": score.auc, "precision_20": score.precision_20, "fps": fps}
        if tracker in configs:
            # Review flags are measured by benchmarks/failure_model.py: they need the tool's failure signals,
            # which this direct tracker run does not compute.
            row["stages_ms"] = {st: 1000 * sum(r["stages"].get(st, 0.0) for r in recs)
                                / sum(r["frames"] - 1 for r in recs) for st in STAGES}
            row["peak_rss_mib"] = max(r["peak_rss_mib"] for r in recs)
        rows.append(row)

    # Trial runs (--no-record) keep their plots beside their results, not over the recorded ones.
    plot_root = args.out / "plots" if args.no_record else HERE / "otb_plots"
    write_report(plot_root, scores)
    markdown = render_markdown(args, trackers, sequences, rows, scores, time.time() - started)
    if seed_table:
        markdown += "\n\n" + seed_table
    markdown += "\n\n" + attribute_section(per_seed, [s.name for s in sequences], plot_root / "attributes", seeds)
    print(markdown)
    if not args.no_record:
        update_section("otb", markdown)


def _seed_root(out: Path, seeds: list[int], seed: int) -> Path:
    """Where one seed's results go: ``out`` for a single seed, ``out/seed<k>`` for several."""
    return out if len(seeds) == 1 else out / f"seed{seed}"


def _display_name(tracker: str) -> str:
    return tracker.upper() if tracker in PEERS else f"SPTPT-{tracker}"


def scores_per_seed(out: Path, seeds: list[int], trackers: list[str], sequences: list[Path],
                    gts: dict) -> dict[str, list[DatasetScore]]:
    """Tracker -> one score per seed it ran with (peers: the first seed only), read from the result files."""
    per: dict[str, list[DatasetScore]] = {}
    for tracker in trackers:
        per[tracker] = []
        for seed in (seeds if tracker not in PEERS else seeds[:1]):
            pairs = {}
            for s in sequences:
                pred = read_otb_boxes(_seed_root(out, seeds, seed) / tracker / f"{s.name}.txt")
                pairs[s.name] = (pred, gts[s.name][: len(pred)])
            per[tracker].append(evaluate_dataset(pairs, tracker=_display_name(tracker)))
    return per


def _seed_table(per_seed: dict[str, list[DatasetScore]], seeds: list[int], trackers: list[str],
                sequences: list[Path]) -> str:
    """Success AUC mean +- std over seeds, per sequence and overall (peers: one deterministic run)."""
    per = {t: np.array([[run.sequences[s.name].auc for s in sequences] for run in per_seed[t]]) for t in trackers}
    names = [_display_name(t) for t in trackers]

    def cell(values: np.ndarray) -> str:
        return f"{values.mean():.3f}" if len(values) == 1 else f"{values.mean():.3f} ± {values.std(ddof=1):.3f}"

    lines = [f"### Success AUC over seeds {', '.join(map(str, seeds))} (mean ± std; peers run once)", "",
             "| Sequence | " + " | ".join(names) + " |", "|---|" + "---:|" * len(trackers)]
    for j, s in enumerate(sequences):
        lines.append(f"| {s.name} | " + " | ".join(cell(per[t][:, j]) for t in trackers) + " |")
    lines.append("| **mean over sequences** | " + " | ".join(cell(per[t].mean(axis=1)) for t in trackers) + " |")
    return "\n".join(lines)


def load_attributes(path: Path = ATTRIBUTES_FILE) -> tuple[dict[str, str], dict[str, list[str]]]:
    """(attribute code -> name, in OTB's order; sequence -> its attribute codes) from ``otb_attributes.json``."""
    doc = json.loads(Path(path).read_text())
    return doc["attributes"], doc["sequences"]


def attribute_groups(labels: dict[str, list[str]], sequences: list[str], codes: list[str],
                     min_sequences: int = MIN_ATTRIBUTE_SEQUENCES) -> dict[str, list[str]]:
    """Attribute code -> the benchmarked sequences that hold it, for attributes held by at least ``min_sequences``."""
    groups = {code: [s for s in sequences if code in labels.get(s, ())] for code in codes}
    return {code: names for code, names in groups.items() if len(names) >= min_sequences}


def attribute_score(runs: list[DatasetScore], names: list[str]) -> DatasetScore:
    """One tracker on the sequences ``names``: unweighted mean over them, then mean over runs (seeds).

    Every run has the same sequences, so the mean over runs of the per-run means is the plain mean over all
    (run, sequence) pairs, which is what ``DatasetScore.from_sequences`` computes.
    """
    return DatasetScore.from_sequences(
        runs[0].tracker, {f"{name}#{k}": run.sequences[name] for k, run in enumerate(runs) for name in names})


def attribute_section(per_seed: dict[str, list[DatasetScore]], sequences: list[str], plot_dir: Path,
                      seeds: list[int], attributes: Path = ATTRIBUTES_FILE) -> str:
    """Draw one success plot per attribute held by enough sequences; return the Markdown table of mean AUC."""
    names, labels = load_attributes(attributes)
    groups = attribute_groups(labels, sequences, list(names))
    table: dict[str, list[DatasetScore]] = {}
    if groups:
        Path(plot_dir).mkdir(parents=True, exist_ok=True)
    for code, members in groups.items():
        table[code] = [attribute_score(runs, members) for runs in per_seed.values()]
        plot_success(table[code], Path(plot_dir) / f"{code}.png",
                     title=f"Success plots of OPE - {names[code]} ({len(members)} sequences)")
    over = "mean over the sequences with the attribute"
    if len(seeds) > 1:
        over += ", SPTPT also over seeds " + ", ".join(map(str, seeds))
    lines = [f"### Success AUC per OTB attribute ({over})", ""]
    if table:
        lines += ["| Tracker | " + " | ".join(f"{code} ({len(groups[code])})" for code in table) + " |",
                  "|---|" + "---:|" * len(table)]
        for k, tracker in enumerate(per_seed):
            lines.append(f"| {_display_name(tracker)} | " + " | ".join(f"{table[c][k].auc:.3f}" for c in table) + " |")
    else:
        lines.append(f"No attribute is held by {MIN_ATTRIBUTE_SEQUENCES} or more of these sequences.")
    few = [f"{code} ({', '.join(m) or 'none'})" for code in names if code not in groups
           for m in [[s for s in sequences if code in labels.get(s, ())]]]
    unlabelled = [s for s in sequences if s not in labels]
    lines += ["", f"Labels: `benchmarks/otb_attributes.json` (OTB-100). Fewer than {MIN_ATTRIBUTE_SEQUENCES} "
              f"sequences, no plot: {'; '.join(few) or 'none'}."
              + (f" Not labelled: {', '.join(unlabelled)}." if unlabelled else "")]
    if table:
        lines.append(f"Plots: `{_shown(Path(plot_dir))}/<CODE>.png`.")
    return "\n".join(lines)


def _shown(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(HERE.parent))
    except ValueError:
        return str(path)


def replot(out: Path, trackers: list[str], sequences: list[Path], *, seeds: list[int], plot_dir: Path) -> str:
    """The per-attribute plots and table from the result files of an earlier run in ``out``; tracks nothing."""
    if not seeds:
        seeds = sorted(int(p.name[4:]) for p in out.glob("seed*") if p.is_dir() and p.name[4:].isdigit()) or [0]
    first = _seed_root(out, seeds, seeds[0])
    found = [t for t in trackers if (first / t).is_dir()]
    if not found:
        raise SystemExit(f"--replot {out}: none of {trackers} has results in {first}")
    missing = [t for t in trackers if t not in found]
    complete = [s for s in sequences
                if all((_seed_root(out, seeds, seed) / t / f"{s.name}.txt").is_file()
                       for t in found for seed in (seeds if t not in PEERS else seeds[:1]))]
    if not complete:
        raise SystemExit(f"--replot {out}: no sequence has results for all of {found} at seeds {seeds}")
    left = [s.name for s in sequences if s not in complete]
    print(f"replot {out}: trackers {found}, seeds {seeds}, {len(complete)} sequences"
          + (f"; no results for trackers {missing}" if missing else "")
          + (f"; sequences without every result left out: {left}" if left else ""), file=sys.stderr)
    gts = {s.name: read_otb_boxes(s / "groundtruth_rect.txt") for s in complete}
    per_seed = scores_per_seed(out, seeds, found, complete, gts)
    return attribute_section(per_seed, [s.name for s in complete], plot_dir, seeds)


def render_markdown(args, trackers, sequences, rows, scores, wall) -> str:
    command = "python -m benchmarks.otb_benchmark " + " ".join(sys.argv[1:])
    frames = sum(len(read_otb_boxes(args.out / trackers[0] / f"{s.name}.txt")) for s in sequences)
    lines = [
        "## OTB accuracy and speed: SPTPT presets and OpenCV peers",
        "",
        f"Command: `{command.strip()}`  ",
        f"Machine: {machine_line()}; workers: {args.workers}; seed {args.seed}; wall time {wall / 60:.1f} min.  ",
        f"Data: {len(sequences)} sequences of `../shared/otb`, {frames} frames"
        + (f" (first {args.stop} of each)" if args.stop else "") + ". One-pass evaluation, IoU > t at 21 thresholds "
        "(continuous areas), precision at 20 px, unweighted mean over sequences; frames/s over frames 2..N.",
        "",
        "| Tracker | Success AUC | Precision@20px | Frames/s |",
        "|---|---:|---:|---:|",
    ]
    for row in sorted(rows, key=lambda r: -r["auc"]):
        lines.append(f"| {row['tracker']} | {row['auc']:.3f} | {row['precision_20']:.3f} | {row['fps']:.1f} |")
    sptpt_rows = [r for r in rows if "stages_ms" in r]
    if sptpt_rows:
        # Stages no benchmarked preset runs (the scale filter, off in every preset) get no column.
        stages = [s for s in STAGES if any(r["stages_ms"][s] > 0 for r in sptpt_rows)]
        lines += ["", "### SPTPT per stage (ms per frame, frames 2..N) and memory", "",
                  "| Preset | " + " | ".join(stages) + " | peak RSS (MiB) |",
                  "|---|" + "---:|" * (len(stages) + 1)]
        for r in sptpt_rows:
            lines.append(f"| {r['tracker']} | " + " | ".join(f"{r['stages_ms'][s]:.1f}" for s in stages)
                         + f" | {r['peak_rss_mib']:.0f} |")
    lines += ["", "### Per sequence (success AUC)", "",
              "| Sequence | " + " | ".join(s.tracker for s in scores) + " |",
              "|---|" + "---:|" * len(scores)]
    for seq in sequences:
        lines.append(f"| {seq.name} | " + " | ".join(f"{s.sequences[seq.name].auc:.3f}" for s in scores) + " |")
    lines += ["", "Plots: `benchmarks/otb_plots/success_plots.png`, `benchmarks/otb_plots/precision_plots.png`."]
    return "\n".join(lines)


def _fmt(value: float) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.3f}"


if __name__ == "__main__":
    main()
