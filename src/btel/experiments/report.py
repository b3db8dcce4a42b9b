"""``docs/results.md`` and ``docs/results.json`` from the latest experiment runs, in one command.

``btel report --runs runs/experiments --docs docs`` reads ``<runs>/<experiment>/results.json``,
copies each experiment's PNGs to ``docs/figures/`` and writes the tables, the commands that
produced them, and a reading computed from the numbers (who wins at which budget, by how much).
Sections other tools maintain in ``docs/results.md`` between ``<!-- name:start -->`` and
``<!-- name:end -->`` markers (e.g. the scale benchmark's) are carried over unchanged.

**Hostile inputs.** Run folders and ``docs/`` may hold anything: only regular files are read or
copied (a symlink to one is followed; one to a device, FIFO, socket or folder is refused before any
byte is read), each at most :data:`MAX_TEXT_BYTES` (``results.json``, ``results.md``,
``reading.md``) or :data:`MAX_FIGURE_BYTES` (a PNG). An existing ``docs/`` output that is not a
regular file is refused, not opened for writing. A ``results.json`` whose fields do not have the
types the report reads is refused with its path, the field and the command that writes it again.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from pathlib import Path
from typing import Any

from ..exceptions import BTELError, DataNotFoundError, InvalidParameterError
from . import EXPERIMENTS
from ..core.storage import format_bytes
from ._common import docstring_markdown

__all__ = ["write_report"]

_TITLES = {
    "accuracy": "(a) Recall vs tolerance at ≤ 2 MB, N = 2000, both directions",
    "vs-n": "(b) Recall@10 vs N at ≤ 0.5 MB (summer → winter)",
    "vs-budget": "(c) Recall@10 vs budget at N = 3576 (summer → winter)",
    "feature-ratio": "(d) BTE-C, feature ratio c = 0.1 … 1, r = 1 (summer → winter, N = 3576)",
    "regions": "(e) BTEL, regions r = 1 … 20, c = 0.1 (summer → winter, N = 3576)",
    "sequence-filter": "(f) Sequence filter a = 5, 20 at N = 3576, ≤ 1 MB (summer → winter)",
    "beyond": "Beyond the paper: BTEL variants vs quantisers at the same bytes (the ladder)",
    "front-ends": "Front ends: normalisation, delta descriptors and whitening, for every method",
    "codes": "Output codes beyond the binary index (btel-codes) vs quantisers, 1 KB … 1 MB",
    "frontier": "The accuracy-per-byte frontier: every method × 1 KB … 1 MB, routes and independent places, auto",
}
_TOLERANCES = (0, 1, 2, 5, 10, 20)
_MARKER = re.compile(r"<!-- (?P<name>[\w-]+):start -->.*?<!-- (?P=name):end -->", re.S)
#: Largest results.json / results.md / reading.md read (16 MiB; the full runs' files are well under 1 MiB).
MAX_TEXT_BYTES = 16 << 20
#: Largest figure copied (64 MiB; the experiments' PNGs are well under 1 MiB).
MAX_FIGURE_BYTES = 64 << 20
#: Row cells that must be numbers (or null) where present: the tables format them as numbers.
_NUMERIC_CELL = re.compile(r"(val_)?(recall@\d+|R@\d+)$|n_places$|budget$|nbytes$|minimum_bytes$|fit_s$|query_us$|window$")


def _read_bytes(path: Path, limit: int) -> bytes:
    """The bytes of the regular file ``path`` (a symlink to one is followed), at most ``limit`` of them.

    Raises
    ------
    DataNotFoundError
        ``path`` cannot be opened.
    InvalidParameterError
        ``path`` is not a regular file (a device, FIFO, socket or folder), or holds more than ``limit`` bytes.
    """
    try:  # O_NONBLOCK: opening a FIFO must not wait for a writer; fstat then refuses it
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise DataNotFoundError(f"{str(path)!r} could not be opened: {exc.strerror}.") from exc
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # checked before fdopen, which refuses a folder on its own terms
        os.close(fd)
        raise InvalidParameterError(f"{str(path)!r} is not a regular file (a device, FIFO, socket or folder); "
                                    "btel report reads and copies files only: remove it or replace it by a file.")
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(limit + 1)  # one byte more than allowed: a file larger than its stat (or growing) is caught
    if len(data) > limit:
        raise InvalidParameterError(f"{str(path)!r} holds more than {limit} bytes, more than btel report reads "
                                    "from one file; it is not an experiment's output.")
    return data


def _read_text(path: Path) -> str:
    """UTF-8 text of a regular file of at most :data:`MAX_TEXT_BYTES` bytes (see :func:`_read_bytes`)."""
    try:
        return _read_bytes(path, MAX_TEXT_BYTES).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidParameterError(f"{str(path)!r} is not UTF-8 text ({exc.reason} at byte {exc.start}).") from exc


def _check_target(path: Path, force: bool = False) -> None:
    """Refuse an output path that exists and is not a regular file (always, with ``force``)."""
    if force or (os.path.lexists(path) and not path.is_file()):
        raise InvalidParameterError(f"{str(path)!r} exists and is not a regular file (a device, FIFO, socket, "
                                    "folder or dangling link); btel report writes files only: remove it.")


def _write_bytes(path: Path, data: bytes) -> None:
    """Replace the content of ``path``: a new file, or an existing regular file (a symlink to one is followed).

    Raises
    ------
    InvalidParameterError
        ``path`` exists and is not a regular file (a device, FIFO, socket, folder or dangling symlink):
        refused before it is opened.
    """
    _check_target(path)
    # No O_TRUNC at open: a FIFO or device swapped in since the check is refused by fstat before any change.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | getattr(os, "O_NONBLOCK", 0), 0o666)
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        _check_target(path, force=True)
    with os.fdopen(fd, "wb") as fh:
        os.ftruncate(fd, 0)
        fh.write(data)


def _damaged(path: Path, name: str, what: str) -> InvalidParameterError:
    return InvalidParameterError(f"{str(path)!r} is not a results file btel report can read: {what}. "
                                 f"Re-run `btel experiment {name}` to write it again.")


def _load_results(path: Path, name: str) -> dict[str, Any]:
    """The payload of ``<runs>/<name>/results.json``, its fields checked for the types the report reads.

    An object with ``rows`` (a list of objects; the cells in :data:`_NUMERIC_CELL` finite numbers or
    null, ``status`` a string) and ``run`` (an object; ``command``, ``date_utc`` strings, ``seconds`` a
    finite number, ``quick`` a boolean, ``versions`` an object, each optional or null).

    Raises
    ------
    InvalidParameterError
        Not JSON, or a field of the wrong type: the message names the file, the field and the fix.
    """
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    try:
        payload = json.loads(_read_text(path))
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError; deep nesting recurses
        if isinstance(exc, BTELError):
            raise
        raise _damaged(path, name, f"not JSON ({exc})") from exc
    if not isinstance(payload, dict):
        raise _damaged(path, name, f"it holds a JSON {type(payload).__name__}, not an object with 'rows' and 'run'")
    rows, run = payload.get("rows"), payload.get("run")
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise _damaged(path, name, "'rows' must be a list of objects")
    if not isinstance(run, dict):
        raise _damaged(path, name, "'run' must be an object")
    for key, ok, what in (("command", lambda v: isinstance(v, str), "a string"),
                          ("date_utc", lambda v: isinstance(v, str), "a string"), ("seconds", number, "a finite number"),
                          ("quick", lambda v: isinstance(v, bool), "true or false"),
                          ("versions", lambda v: isinstance(v, dict), "an object")):
        if run.get(key) is not None and not ok(run[key]):
            raise _damaged(path, name, f"'run.{key}' must be {what}, not {run[key]!r:.40}")
    for i, row in enumerate(rows):
        for cell, value in row.items():
            if (_NUMERIC_CELL.match(cell) and value is not None and not number(value)) or \
                    (cell == "status" and not isinstance(value, str)):
                raise _damaged(path, name, f"'rows[{i}].{cell}' must be {'a string' if cell == 'status' else 'a number or null'}"
                                           f", not {value!r:.40}")
    return payload


def _table(rows: list[dict[str, Any]], extra: list[str]) -> list[str]:
    # recall@t: the point prediction within t frames; R@K (ranked) is a separate column where present.
    head = ["method", *extra, "N", "budget", "bytes", *[f"recall@{t}" for t in _TOLERANCES], "fit s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        method = str(r["method"]) + (" †" if r.get("uses_query_sequence") else "")
        cells = [method, *[str(r.get(k, "")) for k in extra], str(r["n_places"]),
                 format_bytes(r["budget"]) if r.get("budget") else "none"]
        if r.get("status", "ok") != "ok":
            cells += [r["status"], *[""] * len(_TOLERANCES), ""]
        else:
            cells += [format_bytes(r["nbytes"]) if r.get("nbytes") is not None else "?",
                      *[f"{r[f'recall@{t}']:.3f}" for t in _TOLERANCES],
                      f"{r['fit_s']:.1f}" if r.get("fit_s") is not None else "–"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _is_btel(row: dict[str, Any]) -> bool:
    """Is the row's method one that encodes place indices (asked of the method, by its registry name)?"""
    from ..methods.registry import make_method, method_names

    name = str(row.get("registry_name", row["method"]))
    return name in method_names() and make_method(name).encodes_place_index


def _reading(name: str, rows: list[dict[str, Any]]) -> list[str]:
    """Plain statements computed from the rows: the best BTEL variant against the best other method."""
    ok = [r for r in rows if r.get("status", "ok") == "ok" and r.get("window", 0) == 0]
    out: list[str] = []
    groups: dict[Any, list[dict[str, Any]]] = {}
    key = {"accuracy": "direction", "vs-n": "n_places", "vs-budget": "budget"}.get(name)
    if key is None:
        if ok:
            best = max(ok, key=lambda r: r["recall@10"])
            out.append(f"Best recall@10: {best['method']} at {best['recall@10']:.3f} ({format_bytes(best['nbytes'])}).")
        if name == "sequence-filter":
            for base in sorted({r["registry_name"] for r in rows if r.get("status", "ok") == "ok"}):
                series = {r.get("window", 0): r["recall@10"] for r in rows if r["registry_name"] == base
                          and r.get("status", "ok") == "ok"}
                if 0 in series:
                    out.append(f"{base}: recall@10 {series[0]:.3f} raw, " + ", ".join(
                        f"{series[a]:.3f} with a = {a}" for a in sorted(series) if a))
        return out
    for r in ok:
        groups.setdefault(r.get(key), []).append(r)
    for value, group in groups.items():
        budgeted = [r for r in group if r.get("budget")]
        ours = [r for r in budgeted if _is_btel(r)]
        theirs = [r for r in budgeted if not _is_btel(r)]
        if not ours or not theirs:
            continue
        a = max(ours, key=lambda r: r["recall@10"])
        b = max(theirs, key=lambda r: r["recall@10"])
        label = format_bytes(value) if key == "budget" else (f"N = {value}" if key == "n_places" else value)
        verdict = "wins" if a["recall@10"] > b["recall@10"] else ("ties" if a["recall@10"] == b["recall@10"] else "loses")
        out.append(f"{label}: best BTEL ({a['method']}, {format_bytes(a['nbytes'])}) recall@10 = {a['recall@10']:.3f} "
                   f"vs best other ({b['method']}, {format_bytes(b['nbytes'])}) {b['recall@10']:.3f} — BTEL {verdict}.")
    return out


def _beyond_lines(payload: dict[str, Any]) -> list[str]:
    """The "beyond" experiment: ladder, then one table per part (Nordland, Gardens Point, synthetic)."""
    budget = payload.get("budget")
    n = next((r["n_places"] for r in payload["rows"] if r.get("part") == "nordland"), "?")
    lines = [f"Validation protocol {docstring_markdown(payload.get('protocol', {}).get('text', ''))}", "",
             f"### Ladder (Nordland, N = {n}, HOG, ≤ {format_bytes(budget) if budget else '?'})", "",
             "| direction | measure | best BTEL variant (by validation) | its value | best of PQ / OPQ / ITQ | its value "
             "| BTEL ≥ quantiser | chance |", "|---|---|---|---|---|---|---|---|"]
    for direction, measures in payload.get("ladder", {}).items():
        for measure, pick in measures.items():
            ours, theirs = pick.get("btel"), pick.get("quantiser")
            cell = (lambda p: (f"{p['method']} ({format_bytes(p['nbytes'])})", f"{p['value']:.3f}")
                    if p else ("does not fit", "–"))
            a, b = cell(ours), cell(theirs)
            verdict = {True: "yes", False: "no"}.get(pick.get("btel_at_least_quantiser"), "–")
            if "btel_reaches_0.5" in pick:
                verdict += f"; BTEL ≥ 0.5: {'yes' if pick['btel_reaches_0.5'] else 'no'}"
            lines.append(f"| {direction} | {measure} | {a[0]} | {a[1]} | {b[0]} | {b[1]} | {verdict} | "
                         f"{pick.get('chance', float('nan')):.3f} |")
    lines.append("")
    parts = [("nordland", "Nordland, every method and read-out (reported stretches)", ["direction", "decoder"]),
             ("gardens-point", "Gardens Point day → night (NetVLAD 500-D, N = 200), no tuning", []),
             ("synthetic", "Synthetic routes: appearance change between traverses, no tuning", ["condition_shift"])]
    for key, title, extra in parts:
        rows = [dict(r, **{"R@10 (top 10 ranked)": f"{r['R@10']:.3f}" if r.get("R@10") is not None else ""})
                for r in payload["rows"] if r.get("part") == key]
        if rows:
            lines += [f"### {title}", ""] + _table(rows, extra + (["R@10 (top 10 ranked)"] if key == "nordland" else []))
            lines += [""]
    return lines


def _front_ends_lines(payload: dict[str, Any]) -> list[str]:
    """The "front-ends" experiment: one pivot table per part and direction (method × front end), then a reading."""
    rows = [r for r in payload["rows"] if r.get("direction")]
    lines: list[str] = []
    reading: list[str] = []
    for part, direction in dict.fromkeys((r["part"], r["direction"]) for r in rows):
        t = 10 if part == "nordland" else 2
        group = [r for r in rows if r["part"] == part and r["direction"] == direction]
        fronts = list(dict.fromkeys(r["front"] for r in group))
        what = "Nordland HOG" if part == "nordland" else "Gardens Point NetVLAD"
        n = group[0]["n_places"]
        lines += [f"### {what} {direction}, N = {n}: recall@{t} (single frame / HMM)", "",
                  "| method | " + " | ".join(fronts) + " |", "|---|" + "---|" * len(fronts)]
        labels = dict.fromkeys((r["method"], r.get("budget")) for r in group)
        for method, budget in labels:
            cells = []
            for front in fronts:
                found = {r["decoder"]: r for r in group if r["method"] == method and r.get("budget") == budget
                         and r["front"] == front}
                single, hmm = found.get("single"), found.get("HMM")
                if single is None:
                    cells.append("–")
                elif single.get("status", "ok") != "ok":
                    cells.append(single["status"])
                else:
                    mark = " †" if single.get("uses") == "sequence" else ""
                    cells.append(f"{single[f'recall@{t}']:.3f}{mark} / {hmm[f'recall@{t}']:.3f}" if hmm
                                 else f"{single[f'recall@{t}']:.3f}{mark}")
            where = format_bytes(budget) if budget else "no budget"
            lines.append(f"| {method} ({where}) | " + " | ".join(cells) + " |")
            ok = {r["front"]: r[f"recall@{t}"] for r in group if r["method"] == method and r.get("budget") == budget
                  and r["decoder"] == "single" and r.get("status", "ok") == "ok"}
            if "none" in ok and "l2" in ok:
                moves = ", ".join(f"{f} {ok[f] - ok['none']:+.3f}" for f in fronts if f != "none" and f in ok)
                reading.append(f"{what} {direction}, {method} ({where}): recall@{t} {ok['none']:.3f} on raw rows; "
                               f"change by front end: {moves}.")
        lines.append("")
    lines += ["† the front end makes the method use the query sequence (delta descriptors); the HMM column "
              "always does. Nothing was tuned on the reported queries.", ""]
    if reading:
        lines += ["How much each front end moved each method (single frame, against raw rows):", ""]
        lines += [f"- {s}" for s in reading] + [""]
    return lines


def _section(name: str, payload: dict[str, Any], docs_dir: Path) -> list[str]:
    """One experiment's section of results.md: heading, command, then its tables (``payload`` checked
    by :func:`_load_results`; a cell it does not check raises KeyError/TypeError/ValueError here)."""
    rows, run = payload["rows"], payload["run"]
    lines = [f"## {_TITLES[name]}", "",
             f"Command: `{run.get('command') or 'btel experiment ' + name}`"
             f"{' (quick mode)' if run.get('quick') else ''} — {run.get('date_utc') or ''}, "
             f"{run.get('seconds') or 0:.0f} s, btel {(run.get('versions') or {}).get('btel', '?')}.", ""]
    if run.get("quick"):  # the heading names the full run's sizes; say that these rows are not them
        lines += ["> **Quick mode**: a smoke run on smaller maps and budgets than the heading names (the rows "
                  "give them). Its differences are too small to read a verdict from, so none is drawn.", ""]
    if name == "beyond":
        lines += _beyond_lines(payload)
    elif name == "front-ends":
        lines += _front_ends_lines(payload)
    elif name == "codes":
        from .codes import report_lines

        lines += report_lines(payload, docs_dir)
    elif name == "frontier":
        from .frontier import report_lines as frontier_lines

        lines += frontier_lines(payload, docs_dir)
    else:
        extra = {"accuracy": ["direction"], "sequence-filter": ["window"]}.get(name, [])
        lines += _table(rows, extra) + [""]
    return lines


def write_report(runs_dir: str | Path = "runs/experiments", docs_dir: str | Path = "docs",
                 reading_file: str | Path | None = None) -> Path:
    """Write ``docs/results.md`` and ``docs/results.json`` from every experiment found in ``runs_dir``.

    Parameters
    ----------
    reading_file : path, optional
        A hand-written interpretation (Markdown) placed under "Reading"; default
        ``docs/reading.md`` when it exists.

    Returns
    -------
    Path of ``results.md``.
    """
    runs_dir, docs_dir = Path(runs_dir), Path(docs_dir)
    found = {name: runs_dir / name / "results.json" for name in EXPERIMENTS if (runs_dir / name / "results.json").is_file()}
    if not found:
        raise DataNotFoundError(f"no experiment results under {str(runs_dir)!r}; run `btel experiment all` first.")
    figures = docs_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    md_path, json_path = docs_dir / "results.md", docs_dir / "results.json"
    for target in (md_path, json_path):  # refused before any work (and before results.md is read)
        _check_target(target)
    kept = {m.group("name"): m.group(0) for m in _MARKER.finditer(_read_text(md_path))} if md_path.exists() else {}

    # Front matter: the site's navigation column hidden (its table of contents stays), so the wide tables fit.
    lines = ["---", "hide:", "  - navigation", "---", "", "# Results", "",
             "Generated by `btel report` from the latest `btel experiment` runs; do not edit by hand "
             "(except between marker comments, which other benchmark scripts maintain).", "",
             "Data: Nordland `nordland64` (64×32 frames, every 10th frame of the NRK videos, CC BY 3.0), "
             "frame-aligned seasons; tolerance in frames (≈ 200 m each). Descriptor: HOG 3780-D "
             "(9 orientations, 4×4 cells, 2×2 blocks) for every method except SeqSLAM (64×32 patch-normalised "
             "thumbnails). Front end: every method's default, rows L2-normalised (SeqSLAM: none); brute force "
             "searches by cosine on them, its strongest honest form; the front-ends section compares the others. "
             "Budgets are decimal (1 MB = 10⁶ B); every method's bytes follow the one storage rule "
             "(README). Brute force is the unbudgeted reference.", "",
             "Metrics: recall@t = share of queries whose point prediction is within t frames of the true place; "
             "R@K = share with a correct place among the top K ranked candidates (R@1 = recall@0). "
             "† marks methods that use the query sequence (SeqSLAM): not comparable with single-frame methods.", ""]
    summary: dict[str, Any] = {}
    for name, path in found.items():
        payload = _load_results(path, name)
        summary[name] = {"run": payload["run"], "rows": payload["rows"],
                         **{k: v for k, v in payload.items() if k not in ("run", "rows", "curves")}}
        try:
            lines += _section(name, payload, docs_dir)
            reading = ([] if name in ("beyond", "front-ends", "codes", "frontier") or payload["run"].get("quick")
                       else _reading(name, payload["rows"]))
        except BTELError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            # The sections read many experiment-specific cells; a damaged one is named with its file.
            raise _damaged(path, name, f"a field is missing or has the wrong type ({type(exc).__name__}: {exc})") from exc
        for png in sorted((path.parent).glob("*.png")):
            target = figures / f"{name}-{png.name}"
            _write_bytes(target, _read_bytes(png, MAX_FIGURE_BYTES))
            lines += [f"![{name} {png.stem}](figures/{target.name})", ""]
        if reading:
            lines += ["Reading (computed from the table):", ""] + [f"- {s}" for s in reading] + [""]
    missing = [name for name in EXPERIMENTS if name not in found]
    if missing:
        lines += ["## Not yet run", "",
                  "No results yet for: " + ", ".join(f"{_TITLES[n]} (`btel experiment {n}`)" for n in missing)
                  + ". Run them and `btel report` again.", ""]
    reading_path = Path(reading_file) if reading_file else docs_dir / "reading.md"
    if reading_path.is_file():
        lines += ["## Reading", "", _read_text(reading_path).strip(), ""]
    for block in kept.values():
        lines += [block, ""]
    _write_bytes(md_path, "\n".join(lines).encode("utf-8"))
    _write_bytes(json_path, (json.dumps(summary, indent=1) + "\n").encode("utf-8"))
    return md_path
