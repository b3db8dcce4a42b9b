"""Fuzz btel's writers: racing writers and writes that fail part-way (issue 34).

Byte mutations of an input (``fuzz_readers.py``) do not model writers, so the cases here are
seeded *scenarios*. Each case picks a writer — ``save`` (``model.save(path, overwrite=False)``),
``train`` (``btel train -o``), ``extract`` (``btel extract -o``), ``localize`` (``btel localize
-o``) or ``evaluate`` (``btel evaluate --out``) — a umask, and one of two families:

- ``race``  — 2 to 4 writers of one target started together (each after a random 0–40 ms), none
  with ``--overwrite``, the target absent or (one case in five) already there; the summary counts
  how the racers that lost learnt it (``in the race``: another writer published while they wrote;
  ``found the target``: it was there when they checked). **Passes** when
  exactly one writer published (none when the target was there), every other one exited 2 with
  "already exists" (or, for ``extract``, found the winner's matrix up to date and wrote
  nothing), the target is whole (a model that loads, a matrix that reads, a CSV whose rows all
  have the header's width, a run folder whose files all parse) and no temporary or claim is left;
- ``fault`` — one writer under a file size limit (``RLIMIT_FSIZE``, 200 B … 200 KB: a full
  disk, every write past it fails with EFBIG). **Passes** when it exits 0 or 1 with one
  ``Error: … could not write …`` line and no traceback, the target is whole or absent, and no
  temporary or claim is left.

In both families every file a writer created must have the mode ``0666`` less the case's
umask. A case **fails** otherwise, on a traceback, or when a writer does not end within the
timeout (a hang). Writers are forked from this process after ``btel.cli`` is imported (so a case
costs its work, not an interpreter start), with one BLAS/OpenMP thread.

Run (writes ``benchmarks/results/fuzz_writers.json``)::

    python benchmarks/fuzz_writers.py --cases 2000 --seed 0
    python benchmarks/fuzz_writers.py --cases 50 --writers train,evaluate --families race

``--case ID`` reruns one case and prints what each writer said.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # forked writers must not inherit thread pools

import argparse  # noqa: E402
import contextlib  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import random  # noqa: E402
import resource  # noqa: E402
import select  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections import Counter  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

WRITERS = ("save", "train", "extract", "localize", "evaluate")
FAMILIES = ("race", "fault")
UMASKS = (0o022, 0o027, 0o002)
RESULTS = Path(__file__).resolve().parent / "results" / "fuzz_writers.json"
#: Exit code of a writer that raised something the command line did not turn into one line.
_UNCAUGHT = 99


# ------------------------------------------------------------------------------------------- inputs
def build_inputs(folder: Path) -> None:
    """The map, queries, a saved model and an image folder every case reads (made in a child process,
    so this one never starts a thread pool before it forks the writers)."""

    def make() -> None:
        import cv2
        import numpy as np

        from btel.datasets import synthetic_route
        from btel.methods import make_method

        route = synthetic_route(n_places=80, dim=32, seed=5)
        np.save(folder / "db.npy", route.map.astype(np.float32))
        np.save(folder / "q.npy", route.queries.astype(np.float32))
        make_method("bruteforce").fit(route.map).save(folder / "model.npz")
        images = folder / "images"
        images.mkdir()
        rng = np.random.default_rng(0)
        for i in range(6):
            cv2.imwrite(str(images / f"{i:03d}.png"), rng.integers(0, 255, size=(40, 80), dtype=np.uint8))

    code, output = _in_child(make, timeout=300)
    if code != 0:
        raise RuntimeError(f"could not build the inputs:\n{output}")


def _command(writer: str, inputs: Path, target: Path) -> list[str] | None:
    """The ``btel`` arguments of a writer (None: the Python ``save``)."""
    return {
        "save": None,
        "train": ["train", str(inputs / "db.npy"), "-o", str(target), "--method", "btel-c", "--no-progress"],
        "extract": ["extract", str(inputs / "images"), "-o", str(target), "--no-progress"],
        "localize": ["localize", str(inputs / "model.npz"), str(inputs / "q.npy"), "-o", str(target)],
        "evaluate": ["evaluate", "--db", str(inputs / "db.npy"), "--queries", str(inputs / "q.npy"),
                     "--methods", "bruteforce", "--no-reference", "--out", str(target), "--no-progress"],
    }[writer]


def _target_name(writer: str) -> str:
    return {"save": "model.btel.npz", "train": "model.btel.npz", "extract": "x.npy", "localize": "preds.csv",
            "evaluate": "run"}[writer]


# ------------------------------------------------------------------------------------------ children
def _preload() -> None:
    """Import what the writers run (no thread pool starts on import), so each forked writer costs its work."""
    import btel.cli  # noqa: F401
    import btel.descriptors  # noqa: F401
    import btel.evaluation.measure  # noqa: F401
    import btel.methods.baselines.bruteforce  # noqa: F401
    import btel.methods.btel.localizer  # noqa: F401
    import btel.evaluation.plots  # noqa: F401
    import btel.evaluation.runs  # noqa: F401
    import cv2  # noqa: F401
    import faiss  # noqa: F401
    import PIL.Image  # noqa: F401


def _in_child(work: Callable[[], Any], *, timeout: float, delay: float = 0.0, fsize: int | None = None,
              umask: int | None = None) -> tuple[int | None, str]:
    """Run ``work`` in a forked child; return (exit code or None on a hang, its stdout + stderr)."""
    return _collect(*_fork(work, delay, fsize, umask), timeout)


def _fork(work: Callable[[], Any], delay: float, fsize: int | None, umask: int | None) -> tuple[int, int]:
    """Fork a child that runs ``work`` with its output on a pipe (a file size limit does not apply to
    pipes); return (pid, read end). The child never returns from here: it always ends in ``os._exit``."""
    sys.stdout.flush()
    sys.stderr.flush()
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_end)
        return pid, read_end
    code = _UNCAUGHT
    try:
        os.close(read_end)
        os.dup2(write_end, 1)
        os.dup2(write_end, 2)
        sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", closefd=False), write_through=True)
        if umask is not None:
            os.umask(umask)
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        time.sleep(delay)
        result = work()
        code = result if isinstance(result, int) else 0
    except SystemExit as exc:  # click's standalone mode ends every command this way
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - counted as a failure by the harness
        code = _UNCAUGHT
        with contextlib.suppress(BaseException):
            traceback.print_exc()
    finally:
        with contextlib.suppress(BaseException):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)  # never unwind into the harness's frames (they would remove its folders)


def _collect(pid: int, read_end: int, timeout: float) -> tuple[int | None, str]:
    """Read a child's output until it ends; (exit code, or None when killed after ``timeout``; output)."""
    deadline = time.monotonic() + timeout
    chunks: list[bytes] = []
    reading, code, exited = True, None, False
    while reading or not exited:
        if reading:
            ready, _, _ = select.select([read_end], [], [], 0.01)
            if ready:
                data = os.read(read_end, 1 << 16)
                if data:
                    chunks.append(data)
                    continue
                reading = False
        if not exited:  # reaped once only: a second waitpid of the same child fails
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                code, exited = os.waitstatus_to_exitcode(status), True
            elif time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                code, exited, reading = None, True, False
            elif not reading:
                time.sleep(0.005)
    os.close(read_end)
    return code, b"".join(chunks).decode("utf-8", errors="replace")


def _writer_work(writer: str, inputs: Path, target: Path) -> Callable[[], int]:
    args = _command(writer, inputs, target)
    if args is None:
        def save() -> int:
            import btel
            from btel.exceptions import BTELError, OutputExistsError

            model = btel.load(inputs / "model.npz")
            try:
                model.save(target, overwrite=False)
            except OutputExistsError as exc:
                print(f"Error: {exc}", file=sys.stderr)
                return 2
            except (BTELError, OSError) as exc:
                print(f"Error: {exc}", file=sys.stderr)
                return 1
            print(f"model written to {target}")
            return 0
        return save

    def command() -> int:
        from btel.cli import main

        main(args, prog_name="btel", standalone_mode=True)
        return 0
    return command


# ------------------------------------------------------------------------------------------- checks
def whole(writer: str, target: Path) -> str | None:
    """None when ``target`` is whole (or absent), else what is wrong (checked in a child process)."""
    if not target.exists():
        return None

    def check() -> int:
        import numpy as np

        if writer in ("save", "train"):
            import btel

            btel.load(target)
        elif writer == "extract":
            np.load(target, allow_pickle=False)
        elif writer == "localize":
            _whole_csv(target)
        else:
            from PIL import Image

            for path in target.iterdir():
                if path.suffix == ".json":
                    json.loads(path.read_text())
                elif path.suffix == ".csv":
                    _whole_csv(path)
                elif path.suffix == ".png":
                    with Image.open(path) as image:
                        image.load()
        return 0

    code, output = _in_child(check, timeout=120)
    return None if code == 0 else f"{target.name} is not whole: {output.strip()[-300:]}"


def _whole_csv(path: Path) -> None:
    rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    if not rows or any(len(r) != len(rows[0]) for r in rows):
        raise ValueError(f"{path.name}: rows of different widths (cut short?)")


def leftovers(folder: Path, before: set[str]) -> list[str]:
    """Temporaries and claims in ``folder`` (and a run folder below it) that were not there before."""
    names = [p.name for p in folder.iterdir() if p.name not in before and p.name.startswith(".")]
    for sub in folder.iterdir():
        if sub.is_dir() and sub.name not in before:
            names += [f"{sub.name}/{p.name}" for p in sub.iterdir() if p.name.startswith(".")]
    return names


def wrong_modes(folder: Path, before: set[str], umask: int) -> list[str]:
    want = 0o666 & ~umask
    out = []
    for path in folder.iterdir():
        if path.name in before:
            continue
        files = [path] if path.is_file() else [p for p in path.iterdir() if p.is_file()] if path.is_dir() \
            else []
        modes = {p.name: p.stat().st_mode & 0o777 for p in files}
        out += [f"{name}: {oct(mode)}" for name, mode in modes.items() if mode != want]
    return out


# -------------------------------------------------------------------------------------------- cases
def make_case(seed: int, case_id: int, writers: tuple[str, ...] = WRITERS,
              families: tuple[str, ...] = FAMILIES) -> dict[str, Any]:
    """The scenario of case ``case_id`` (reproducible from the seed)."""
    rng = random.Random(f"{seed}:writers:{case_id}")
    family = families[case_id % len(families)]
    writer = writers[(case_id // len(families)) % len(writers)]
    case: dict[str, Any] = {"id": case_id, "family": family, "writer": writer, "umask": rng.choice(UMASKS)}
    if family == "race":
        case["writers"] = rng.randint(2, 4)
        case["delays"] = [round(rng.uniform(0, 0.04), 4) for _ in range(case["writers"])]
        case["existing"] = rng.random() < 0.2
    else:
        case["fsize"] = int(10 ** rng.uniform(2.3, 5.3))  # 200 B … 200 KB
    return case


def run_case(case: dict[str, Any], inputs: Path, work: Path, *, timeout: float = 120.0) -> dict[str, Any]:
    """Run one case in the empty folder ``work``; return its outcome (``ok`` or a failure and why)."""
    writer = case["writer"]
    target = work / _target_name(writer)
    if case["family"] == "race" and case["existing"]:
        if writer == "evaluate":
            target.mkdir()
            (target / "metrics.json").write_text("{}\n")
        else:
            target.write_bytes(b"kept")
    before = {p.name for p in work.iterdir()}
    if target.is_dir():
        before |= {f"{target.name}/{p.name}" for p in target.iterdir()}
    job = _writer_work(writer, inputs, target)
    if case["family"] == "race":
        children = [_fork(job, delay, None, case["umask"]) for delay in case["delays"]]
        codes, outputs = (list(t) for t in zip(*(_collect(pid, fd, timeout) for pid, fd in children)))
    else:
        code, output = _in_child(job, timeout=timeout, fsize=case["fsize"], umask=case["umask"])
        codes, outputs = [code], [output]
    problems = _judge(case, codes, outputs, target)
    if not problems:
        problem = whole(writer, target) if not (case["family"] == "race" and case["existing"]) else None
        problems += [problem] if problem else []
    left = leftovers(work, before)
    problems += [f"left behind: {left}"] if left else []
    modes = wrong_modes(work, before, case["umask"])
    problems += [f"modes: {modes}"] if modes else []
    outcome = "ok" if not problems else ("hang" if None in codes else "traceback"
                                         if any("Traceback" in o for o in outputs) else "wrong")
    # How each racer that did not publish learnt it: at publish time (the race itself) or before writing.
    racing = ("while this one was writing", "is writing to")
    lost = Counter("in the race" if any(r in o for r in racing) else "found the target"
                   for c, o in zip(codes, outputs) if c == 2) if case["family"] == "race" else Counter()
    return {"outcome": outcome, "codes": codes, "problems": problems, "lost": dict(lost),
            "outputs": [o.strip()[-400:] for o in outputs]}


def _judge(case: dict[str, Any], codes: list[int | None], outputs: list[str], target: Path) -> list[str]:
    problems = []
    if None in codes:
        return [f"a writer did not end within the timeout: codes {codes}"]
    if any("Traceback" in o for o in outputs) or _UNCAUGHT in codes:
        return ["a traceback"]
    if case["family"] == "race":
        wrote = [i for i, (c, o) in enumerate(zip(codes, outputs)) if c == 0 and "up to date" not in o]
        want = 0 if case["existing"] else 1
        if len(wrote) != want:
            problems.append(f"{len(wrote)} writers published (want {want}): codes {codes}")
        for c, o in zip(codes, outputs):
            if c == 2 and "already exists" not in o and "is writing to" not in o:
                problems.append(f"exit 2 without saying the target exists: {o.strip()[-200:]}")
            if c not in (0, 2):
                problems.append(f"exit {c}: {o.strip()[-200:]}")
        if case["existing"] and target.is_file() and target.read_bytes() != b"kept":
            problems.append("the existing file was replaced")
    else:
        code, output = codes[0], outputs[0].strip()
        if code not in (0, 1):
            problems.append(f"exit {code}: {output[-200:]}")
        elif code == 1:
            errors = [line for line in output.splitlines() if line.startswith("Error:")]
            if len(errors) != 1 or ("could not write" not in errors[0] and "cannot save" not in errors[0]):
                problems.append(f"not one 'could not write' error line: {output[-300:]}")
    return problems


def run_cases(n_cases: int, *, seed: int = 0, writers: tuple[str, ...] = WRITERS,
              families: tuple[str, ...] = FAMILIES, timeout: float = 120.0, progress: bool = False,
              deadline: float | None = None) -> dict[str, Any]:
    """Run ``n_cases`` cases; return the summary (see the module docstring)."""
    _preload()

    summary: dict[str, Any] = {"seed": seed, "cases": 0, "outcomes": {}, "by_case": {}, "failed_cases": []}
    counts: Counter[str] = Counter()
    by_case: Counter[str] = Counter()
    lost: Counter[str] = Counter()
    with tempfile.TemporaryDirectory(prefix="btel-fuzz-writers-") as tmp:
        inputs = Path(tmp) / "inputs"
        inputs.mkdir()
        build_inputs(inputs)
        for case_id in range(n_cases):
            if deadline is not None and time.time() > deadline:
                break
            case = make_case(seed, case_id, writers, families)
            work = Path(tmp) / f"case{case_id}"
            work.mkdir()
            result = run_case(case, inputs, work, timeout=timeout)
            counts[result["outcome"]] += 1
            lost.update(result["lost"])
            by_case[f"{case['family']}/{case['writer']}"] += 1
            if result["outcome"] != "ok":
                summary["failed_cases"].append({**case, **result})
            summary["cases"] += 1
            _remove(work)
            if progress and summary["cases"] % 50 == 0:
                print(f"{summary['cases']} cases {dict(counts)}", flush=True)
    summary["outcomes"] = dict(counts)
    summary["racers_refused"] = dict(lost)
    summary["by_case"] = dict(sorted(by_case.items()))
    summary["failures"] = summary["cases"] - counts["ok"]
    summary["failed_cases"] = summary["failed_cases"][:50]
    return summary


def _remove(folder: Path) -> None:
    import shutil

    shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--writers", default=",".join(WRITERS))
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--timeout", type=float, default=120.0)
    parser.add_argument("--minutes", type=float, default=None, help="stop after this long")
    parser.add_argument("--out", default=str(RESULTS))
    parser.add_argument("--case", type=int, default=None, help="rerun one case and print its writers' output")
    args = parser.parse_args()
    writers = tuple(w for w in args.writers.split(",") if w)
    families = tuple(f for f in args.families.split(",") if f)
    if args.case is not None:
        _preload()
        case = make_case(args.seed, args.case, writers, families)
        with tempfile.TemporaryDirectory(prefix="btel-fuzz-writers-") as tmp:
            inputs = Path(tmp) / "inputs"
            inputs.mkdir()
            build_inputs(inputs)
            (Path(tmp) / "work").mkdir()
            result = run_case(case, inputs, Path(tmp) / "work", timeout=args.timeout)
            print(json.dumps({**case, **result}, indent=1))
        return
    start = time.time()
    deadline = None if args.minutes is None else start + 60 * args.minutes
    summary = run_cases(args.cases, seed=args.seed, writers=writers, families=families, timeout=args.timeout,
                        progress=True, deadline=deadline)
    summary["seconds"] = round(time.time() - start, 1)
    summary["command"] = " ".join([Path(sys.executable).name, *sys.argv])
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"{summary['cases']} cases {summary['outcomes']} by case {summary['by_case']}; racers refused "
          f"{summary['racers_refused']}")
    print(f"failures: {summary['failures']} ({summary['seconds']} s); written to {args.out}")


if __name__ == "__main__":
    main()
