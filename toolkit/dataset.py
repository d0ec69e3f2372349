"""Measured input/output data: one or more experiments with named, uniformly sampled signals.

Arrays are ``(n_samples, n_signals)``.  Identification concatenates regressors built per
experiment, never the raw signals, so the boundary between two experiments never creates a
false transition.  Every problem in a file is collected and reported at once.

Examples
--------
>>> import numpy as np
>>> t = np.arange(100) * 0.03
>>> ds = Dataset.from_arrays(u=np.c_[np.sin(t), np.cos(t)], y=np.c_[t**2], dt=0.03,
...                          inputs=["F1", "F2"], outputs=["q1"])
>>> ds.n_samples, ds.inputs, ds.outputs
(100, ('F1', 'F2'), ('q1',))
"""

from __future__ import annotations

import csv
import hashlib
import io
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import DataError
from .files import check_input_file

FloatArray = NDArray[np.float64]

#: Relative tolerance on sample-time uniformity: every step must be within this fraction of
#: the median step (camera time stamps jitter a little; resampling is the user's decision).
DT_TOLERANCE = 0.01


@dataclass(frozen=True, eq=False)
class Experiment:
    """One uninterrupted record: time ``t`` (n,), inputs ``u`` (n, nu), outputs ``y`` (n, ny).

    ``extra`` holds every other numeric column of the source (e.g. ``q3`` or ``ee_x``);
    ``units`` the units its file's header gave (``q1 [rad]``), by column name.
    """

    t: FloatArray
    u: FloatArray
    y: FloatArray
    name: str = ""
    extra: dict[str, FloatArray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])


@dataclass(frozen=True, eq=False)
class Dataset:
    """Named inputs and outputs over one or more experiments with one sample time ``dt``."""

    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    experiments: tuple[Experiment, ...]
    dt: float
    units: dict[str, str] = field(default_factory=dict)

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        u: FloatArray,
        y: FloatArray,
        dt: float,
        inputs: Sequence[str] | None = None,
        outputs: Sequence[str] | None = None,
        *,
        t0: float = 0.0,
        name: str = "",
        extra: dict[str, FloatArray] | None = None,
    ) -> Dataset:
        """One experiment from arrays; names default to ``u1..`` and ``y1..``."""
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
        if y.ndim == 1:
            y = y[:, None]
        problems: list[str] = []
        if u.ndim != 2 or y.ndim != 2:
            problems.append(
                f"u and y must be 2-d (n_samples, n_signals); found {u.shape}, {y.shape}."
            )
        elif u.shape[0] != y.shape[0]:
            problems.append(f"u has {u.shape[0]} samples but y has {y.shape[0]}.")
        if not (np.isfinite(dt) and dt > 0):
            problems.append(f"dt must be a positive number of seconds, found {dt!r}.")
        if problems:
            raise DataError("Cannot build a dataset from these arrays:", problems)
        inputs = (
            tuple(inputs) if inputs is not None else tuple(f"u{i + 1}" for i in range(u.shape[1]))
        )
        outputs = (
            tuple(outputs) if outputs is not None else tuple(f"y{i + 1}" for i in range(y.shape[1]))
        )
        t = np.asarray(t0 + dt * np.arange(u.shape[0]), dtype=np.float64)
        exp = Experiment(t=t, u=u.copy(), y=y.copy(), name=name, extra=dict(extra or {}))
        ds = cls(inputs=inputs, outputs=outputs, experiments=(exp,), dt=float(dt))
        ds.validate(source=name or "arrays")
        return ds

    @classmethod
    def from_csv(
        cls,
        paths: str | Path | Sequence[str | Path],
        inputs: Sequence[str],
        outputs: Sequence[str],
        *,
        time: str = "t",
        dt_tolerance: float = DT_TOLERANCE,
        min_samples: int = 2,
        require_outputs: bool = True,
        units: Mapping[str, str] | None = None,
    ) -> Dataset:
        """Read one experiment per CSV file (header row, time column ``time`` in seconds).

        A header cell may carry its unit in brackets, ``q1 [rad]``: the column is ``q1`` and
        its unit ``rad`` (:func:`split_header`).  ``units`` gives units for columns whose header
        has none; a unit that contradicts the header, or two files that give one column
        different units, are problems.  Every problem in every file is collected and reported
        in one :class:`DataError`.
        """
        if isinstance(paths, str | Path):
            paths = [paths]
        problems: list[str] = []
        exps: list[Experiment] = []
        dts: list[float] = []
        requested = [*inputs, *outputs]
        found: dict[str, tuple[str, str]] = {}  # column -> (unit, file that said so)
        for path in paths:
            exp, dt, probs = _read_csv(Path(path), list(inputs), list(outputs), time, dt_tolerance)
            problems.extend(probs)
            if exp is not None:
                exps.append(exp)
                dts.append(dt)
                for name, unit in exp.units.items():
                    if name not in requested:
                        continue
                    if name in found and found[name][0] != unit:
                        problems.append(
                            f"column {name!r} is in {found[name][0]!r} in {found[name][1]} but in "
                            f"{unit!r} in {path}."
                        )
                    found.setdefault(name, (unit, str(path)))
        merged = {name: unit for name, (unit, _) in found.items()}
        for name, unit in (units or {}).items():
            unit_problem = _unit_problem(unit)
            if unit_problem:
                problems.append(f"unit of {name!r}: {unit_problem}")
            elif name not in requested:
                problems.append(
                    f"a unit is given for {name!r}, which is not an input or output "
                    f"({', '.join(requested)})."
                )
            elif name in merged and merged[name] != unit:
                problems.append(
                    f"column {name!r}: the header says {merged[name]!r}, the units given say "
                    f"{unit!r}."
                )
            else:
                merged[name] = unit
        if dts and max(dts) - min(dts) > dt_tolerance * min(dts):
            problems.append(f"the files have different sample times: {sorted(set(dts))} s.")
        if problems:
            raise DataError("The data cannot be used:", problems)
        ds = cls(
            inputs=tuple(inputs),
            outputs=tuple(outputs),
            experiments=tuple(exps),
            dt=float(dts[0]),
            units=merged,
        )
        problems = validation_problems(
            ds, min_samples, require_outputs, files=[str(p) for p in paths]
        )
        if problems:
            raise DataError(f"The data from {', '.join(map(str, paths))} cannot be used:", problems)
        return ds

    # -- checks ------------------------------------------------------------------------
    def validate(
        self, source: str = "dataset", min_samples: int = 2, require_outputs: bool = True
    ) -> None:
        """Check names, shapes, finiteness, constant columns and length; report all problems."""
        p = validation_problems(self, min_samples, require_outputs)
        if p:
            raise DataError(f"The data from {source} cannot be used:", p)

    # -- views -------------------------------------------------------------------------
    @property
    def nu(self) -> int:
        """Number of inputs."""
        return len(self.inputs)

    @property
    def ny(self) -> int:
        """Number of outputs."""
        return len(self.outputs)

    @property
    def n_samples(self) -> int:
        """Total samples over all experiments."""
        return sum(e.n_samples for e in self.experiments)

    @property
    def u(self) -> FloatArray:
        """All inputs stacked over experiments (for display and metrics, not for regressors)."""
        return np.vstack([e.u for e in self.experiments])

    @property
    def y(self) -> FloatArray:
        """All outputs stacked over experiments."""
        return np.vstack([e.y for e in self.experiments])

    def signal(self, name: str) -> FloatArray:
        """A named column (input, output or extra) stacked over experiments."""
        parts = []
        for e in self.experiments:
            if name in self.inputs:
                parts.append(e.u[:, self.inputs.index(name)])
            elif name in self.outputs:
                parts.append(e.y[:, self.outputs.index(name)])
            elif name in e.extra:
                parts.append(e.extra[name])
            else:
                raise DataError(
                    f"Column {name!r} is not in the dataset. Columns: {', '.join(self.columns)}."
                )
        return np.concatenate(parts)

    @property
    def columns(self) -> list[str]:
        """All column names: inputs, outputs, then the extra columns of the first experiment."""
        extra = list(self.experiments[0].extra) if self.experiments else []
        return [*self.inputs, *self.outputs, *extra]

    def split(self, fraction: float = 0.7) -> tuple[Dataset, Dataset]:
        """Train/validation split in time: the first ``fraction`` of every experiment trains.

        Returns
        -------
        (Dataset, Dataset)
            Training and validation sets with the same signals.
        """
        if not 0.0 < fraction < 1.0:
            raise DataError(f"The split fraction must be in (0, 1), found {fraction}.")
        a, b = [], []
        for e in self.experiments:
            k = round(fraction * e.n_samples)
            a.append(_slice(e, slice(0, k), f"{e.name}[train]"))
            b.append(_slice(e, slice(k, None), f"{e.name}[valid]"))
        return self.with_experiments(a), self.with_experiments(b)

    def blocked_folds(self, k: int, min_held: int, min_piece: int) -> list[tuple[Dataset, Dataset]]:
        """Blocked cross-validation folds in time: ``(fit, held)`` pairs.

        Every experiment is cut into ``k`` contiguous blocks; fold ``j`` holds block ``j`` of
        every experiment out (blocks shorter than ``min_held`` samples stay in), and fits on
        the rest: the pieces before and after the block, each its own experiment (pieces
        shorter than ``min_piece`` are dropped).  Folds with nothing held out or nothing to
        fit are left out, so the list may be empty.
        """
        out = []
        for j in range(k):
            fit, held = [], []
            for e in self.experiments:
                edges = np.linspace(0, e.n_samples, k + 1).round().astype(int)
                a, b = int(edges[j]), int(edges[j + 1])
                if b - a < min_held:
                    fit.append(e)
                    continue
                held.append(_slice(e, slice(a, b), f"{e.name}[{a}:{b}]"))
                fit += [
                    _slice(e, slice(s0, s1), f"{e.name}[{s0}:{s1}]")
                    for s0, s1 in ((0, a), (b, e.n_samples))
                    if s1 - s0 >= min_piece
                ]
            if held and fit:
                out.append((self.with_experiments(fit), self.with_experiments(held)))
        return out

    def with_experiments(self, experiments: Iterable[Experiment]) -> Dataset:
        """A dataset with the same signals and other experiments."""
        return Dataset(
            inputs=self.inputs,
            outputs=self.outputs,
            experiments=tuple(experiments),
            dt=self.dt,
            units=dict(self.units),
        )

    def select(self, inputs: Sequence[str], outputs: Sequence[str]) -> Dataset:
        """Re-select inputs and outputs by name among all columns (inputs, outputs, extras)."""
        problems = [
            f"column {n!r} is not in the dataset"
            for n in (*inputs, *outputs)
            if n not in self.columns
        ]
        if problems:
            raise DataError(f"Cannot select; columns are {', '.join(self.columns)}:", problems)
        exps = []
        for e in self.experiments:
            cols = {**dict(zip(self.inputs, e.u.T)), **dict(zip(self.outputs, e.y.T)), **e.extra}
            exps.append(
                Experiment(
                    t=e.t,
                    u=np.column_stack([cols[n] for n in inputs]),
                    y=np.column_stack([cols[n] for n in outputs]),
                    name=e.name,
                    extra={k: v for k, v in cols.items() if k not in (*inputs, *outputs)},
                )
            )
        return Dataset(tuple(inputs), tuple(outputs), tuple(exps), self.dt, dict(self.units))

    def concat(self, other: Dataset) -> Dataset:
        """The experiments of both datasets (same signals and sample time)."""
        if (other.inputs, other.outputs) != (self.inputs, self.outputs):
            raise DataError(
                f"Cannot join datasets with different signals: {self.inputs}->{self.outputs} and "
                f"{other.inputs}->{other.outputs}."
            )
        if abs(other.dt - self.dt) > DT_TOLERANCE * self.dt:
            raise DataError(f"Cannot join datasets sampled at {self.dt} s and {other.dt} s.")
        return self.with_experiments([*self.experiments, *other.experiments])

    def hash(self) -> str:
        """SHA-256 of names, sample time and values (provenance of identified models)."""
        h = hashlib.sha256()
        h.update(repr((self.inputs, self.outputs, round(self.dt, 12))).encode())
        for e in self.experiments:
            h.update(np.ascontiguousarray(e.u, dtype=np.float64).tobytes())
            h.update(np.ascontiguousarray(e.y, dtype=np.float64).tobytes())
        return h.hexdigest()


def _slice(e: Experiment, s: slice, name: str) -> Experiment:
    return Experiment(
        t=e.t[s], u=e.u[s], y=e.y[s], name=name, extra={k: v[s] for k, v in e.extra.items()}
    )


def validation_problems(
    ds: Dataset,
    min_samples: int = 2,
    require_outputs: bool = True,
    files: Sequence[str] | None = None,
) -> list[str]:
    """Every problem that makes ``ds`` unusable, as a list of sentences.

    ``files``: the CSV file of each experiment, which then names its problems, rows
    numbered as in the file (the header is row 1), as the reader's own problems are.
    """
    p: list[str] = []
    names = [*ds.inputs, *ds.outputs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        p.append(f"each signal may be used once, as an input or an output; repeated: {dup}.")
    if not ds.outputs and require_outputs:
        p.append("at least one output is needed.")
    if not ds.experiments:
        p.append("the dataset has no experiments.")
    for i, e in enumerate(ds.experiments):
        if files is not None:
            label = f"{files[i]}: "
        else:
            label = f"experiment {e.name!r}: " if len(ds.experiments) > 1 else ""
        first_row = 2 if files is not None else 1  # the row of the first sample
        if e.u.shape != (e.n_samples, ds.nu) or e.y.shape != (e.n_samples, ds.ny):
            p.append(f"{label}arrays have shapes u{e.u.shape}, y{e.y.shape}, t{e.t.shape}.")
            continue
        if e.n_samples < min_samples:
            p.append(f"{label}{e.n_samples} samples; at least {min_samples} are needed.")
        for names_, arr, kind in ((ds.inputs, e.u, "input"), (ds.outputs, e.y, "output")):
            for j, n in enumerate(names_):
                col = arr[:, j]
                bad = ~np.isfinite(col)
                if bad.any():
                    first = int(np.argmax(bad))
                    p.append(
                        f"{label}{kind} {n!r} has {int(bad.sum())} NaN/inf values (first at row "
                        f"{first + first_row}, t = {e.t[first]:g} s)."
                    )
                elif e.n_samples > 1 and np.ptp(col) == 0:
                    p.append(
                        f"{label}{kind} {n!r} is constant ({col[0]:g}); it carries no information."
                    )
    return p


#: Inputs whose centred, scaled columns have a singular value below this share of the largest
#: are linearly dependent (:func:`dependent_inputs`).  Data written at a fixed resolution
#: keep a dependence only to that resolution: tensions of std 20 N rounded to 1e-4 N leave
#: about 2e-6; measured tensions with 0.3 N of noise about 1e-2.
DEPENDENT_INPUTS = 1e-5


def _null_directions(z: np.ndarray) -> tuple[np.ndarray, int]:
    """``(vt, k)``: the right singular vectors of ``z`` and how many of the last are null
    (singular value below :data:`DEPENDENT_INPUTS` times the largest)."""
    _, sv, vt = np.linalg.svd(z, full_matrices=False)
    return vt, int(np.sum(sv < DEPENDENT_INPUTS * sv[0]))


def _reduced(rows: np.ndarray) -> np.ndarray:
    """``rows`` (a basis of the null directions) in reduced row echelon form: each row then
    involves as few inputs as the basis allows (two separate dependences stay apart)."""
    m = rows.copy()
    r = 0
    for col in range(m.shape[1]):
        if r == m.shape[0]:
            break
        p = r + int(np.argmax(np.abs(m[r:, col])))
        if abs(m[p, col]) < 1e-6:
            continue
        m[[r, p]] = m[[p, r]]
        m[r] /= m[r, col]
        for i in range(m.shape[0]):
            if i != r:
                m[i] -= m[i, col] * m[r]
        r += 1
    return m


def dependent_inputs(ds: Dataset) -> str | None:
    """Why the inputs of ``ds`` cannot be told apart, or None.

    Over all experiments together, an input that is an exact affine function of the others
    (an input recorded twice, a tension and its antagonist at a constant pretension in every
    record) carries nothing the others do not: a model fitted to these data splits their
    effect by least squares (minimum norm), and predicts correctly only where the inputs
    keep that relation.  Several records at different pretensions tell the tendons apart
    (their levels differ), and are not reported.  Not a problem of the data (they can still
    be modelled), a warning (``identify``, ``diagnose``).  Each pair that is dependent is
    named (``b = k·a + c``); a dependence among more inputs that remains once one input of
    each pair is left out is named as a constant combination.  Constant inputs are problems
    of their own (:func:`validation_problems`) and are left out here.
    """
    if ds.nu < 2 or not ds.experiments:
        return None
    u = np.concatenate([e.u for e in ds.experiments])
    if u.shape[0] < 2 or not np.all(np.isfinite(u)):
        return None
    spread = u.std(axis=0)
    keep = [int(i) for i in np.flatnonzero(spread > 0)]
    if len(keep) < 2:
        return None
    z = (u - u.mean(axis=0)) / np.where(spread > 0, spread, 1.0)
    if _null_directions(z[:, keep])[1] == 0:
        return None
    said: list[str] = []
    involved: list[int] = []
    dropped: set[int] = set()
    for x, a in enumerate(keep):
        for b in keep[x + 1 :]:
            if a in dropped or b in dropped or _null_directions(z[:, [a, b]])[1] == 0:
                continue
            k, c = np.polyfit(u[:, a], u[:, b], 1)
            c = c if abs(c) > 1e-9 * float(np.abs(u[:, b]).max()) else 0.0
            sign = "+" if c >= 0 else "-"
            said.append(f"{ds.inputs[b]} = {k:.6g}·{ds.inputs[a]} {sign} {abs(c):.6g}")
            involved += [i for i in (a, b) if i not in involved]
            dropped.add(b)
    rest = [i for i in keep if i not in dropped]
    vt, null = _null_directions(z[:, rest]) if len(rest) >= 2 else (None, 0)
    for v in _reduced(vt[len(rest) - null :]) if vt is not None and null else []:
        names = [rest[i] for i in np.flatnonzero(np.abs(v) > 1e-3 * np.abs(v).max())]
        said.append(f"a linear combination of {', '.join(ds.inputs[i] for i in names)} is constant")
        involved += [i for i in names if i not in involved]
    how = "; ".join(said)
    return (
        f"the inputs {', '.join(ds.inputs[i] for i in involved)} are linearly dependent in "
        f"every sample ({how}): the data cannot tell their effects apart, so a model fitted "
        "to them splits the effect between them (least squares, minimum norm) and predicts "
        "correctly only while they keep that relation; record them varying independently, "
        "or give one of them only."
    )


#: Largest magnitude accepted in data: squares (error energies, fits) must stay finite.
MAX_MAGNITUDE = 1e150


def _decode(raw: bytes, where: str) -> tuple[str | None, str | None]:
    """CSV bytes as text (UTF-8, with or without BOM, or UTF-16 with a BOM), or a problem."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16"), None
        except UnicodeDecodeError as exc:
            return None, f"{where}: cannot be read as UTF-16 text ({exc})."
    if b"\x00" in raw[:4096]:
        return None, (
            f"{where}: the file contains NUL bytes — probably UTF-16 without a byte-order mark; "
            "save it as UTF-8 (or UTF-16 with a BOM)."
        )
    try:
        return raw.decode("utf-8-sig"), None
    except UnicodeDecodeError as exc:
        return None, f"{where}: is not UTF-8 text ({exc}); save it as UTF-8."


def _rows(numbers: list[int], limit: int = 5) -> str:
    shown = ", ".join(str(n) for n in numbers[:limit])
    return shown + (f" and {len(numbers) - limit} more" if len(numbers) > limit else "")


def _read_csv(
    path: Path, inputs: list[str], outputs: list[str], time: str, dt_tol: float
) -> tuple[Experiment | None, float, list[str]]:
    """Parse one CSV file; never raises for data problems, returns them instead."""
    where = str(path)
    problems: list[str] = []
    if not check_input_file(path, problems, what="data file"):
        return None, 0.0, problems
    try:
        raw = path.read_bytes()
    except OSError as exc:
        return None, 0.0, [f"{where}: cannot be read ({exc.strerror or exc})."]
    text, why = _decode(raw, where)
    if text is None:
        return None, 0.0, [str(why)]
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        header = next(reader, None)
        rows = list(reader)
    except csv.Error as exc:
        return None, 0.0, [f"{where}: cannot be read as CSV text ({exc})."]
    if not header:
        return None, 0.0, [f"{where}: the file is empty; a header row is expected."]
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()  # trailing blank lines end many files
    p: list[str] = []
    split = [split_header(h) for h in header]
    header = [name for name, _ in split]
    file_units = {name: unit for name, unit in split if unit}
    for name, unit in file_units.items():
        unit_problem = _unit_problem(unit)
        if unit_problem:
            p.append(f"{where}: unit of column {name!r}: {unit_problem}")
    dup_cols = sorted({h for h in header if header.count(h) > 1})
    if dup_cols:
        p.append(f"{where}: duplicate column names in the header: {dup_cols}.")
    cols = ", ".join(header)
    if len(header) == 1 and any(s in header[0] for s in (";", "\t", "|")):
        sep = next(s for s in (";", "\t", "|") if s in header[0])
        p.append(
            f"{where}: the header is one column {header[0]!r}: the file seems separated by "
            f"{sep!r}; tendonkit reads comma-separated values (save it as CSV with ',')."
        )
        return None, 0.0, p
    for kind, names in (("time", [time]), ("input", inputs), ("output", outputs)):
        for n in names:
            if n not in header:
                hint = " (name the time column with --time NAME, or time= in Python)"
                p.append(
                    f"{where}: {kind} column {n!r} is not in the file"
                    f"{hint if kind == 'time' else ''}. Columns: {cols}."
                )
    requested = [time, *inputs, *outputs]
    dup_req = sorted({n for n in requested if requested.count(n) > 1})
    if dup_req:
        p.append(f"{where}: columns used more than once as time/input/output: {dup_req}.")
    if p:
        return None, 0.0, p
    values = np.full((len(rows), len(header)), np.nan)
    idx_all = {h: j for j, h in enumerate(header)}
    bad_cells: list[str] = []
    ragged: list[int] = []
    blank: list[int] = []
    bad_time = 0  # cells of the time column that are not numbers (reported with the others)
    for i, row in enumerate(rows):
        if len(row) != len(header):
            (ragged if any(c.strip() for c in row) else blank).append(i + 2)
            continue
        for j, cell in enumerate(row):
            try:
                values[i, j] = float(cell)
            except ValueError:
                bad_time += header[j] == time
                if len(bad_cells) < 5 and header[j] in requested:
                    bad_cells.append(f"row {i + 2}, column {header[j]!r}: {cell!r}")
                elif header[j] in requested:
                    bad_cells.append("")
    if ragged:
        p.append(
            f"{where}: {len(ragged)} rows do not have {len(header)} fields (rows {_rows(ragged)})."
        )
    if blank:
        p.append(f"{where}: blank lines inside the data (rows {_rows(blank)}).")
    for h in requested:
        if h in idx_all:
            col = values[:, idx_all[h]]
            huge = np.flatnonzero(np.isfinite(col) & (np.abs(col) > MAX_MAGNITUDE))
            if huge.size:
                p.append(
                    f"{where}: column {h!r} has values beyond ±{MAX_MAGNITUDE:g} (row "
                    f"{_rows([int(k) + 2 for k in huge])}): a corrupt sample? Their squares "
                    "overflow double precision."
                )
    shown = [c for c in bad_cells if c]
    if bad_cells:
        more = f" (and {len(bad_cells) - len(shown)} more)" if len(bad_cells) > len(shown) else ""
        p.append(f"{where}: non-numeric values: {'; '.join(shown)}{more}.")
    idx = {h: j for j, h in enumerate(header)}
    t = values[:, idx[time]]
    t_unit = file_units.get(time, "")
    if t_unit:  # a time column with its unit: read in seconds
        scale = TIME_UNITS.get(t_unit)
        if scale is None:
            p.append(
                f"{where}: time column {time!r} is in {t_unit!r}; tendonkit reads time in "
                f"{', '.join(TIME_UNITS)}."
            )
        else:
            t = t * scale
            file_units = {**file_units, time: "s"}
    dt = 0.0
    # rows already reported (ragged, blank, a time that is not a number) are not reported
    # again: the time checks run on the other rows, numbered as in the file
    read = np.ones(len(rows), dtype=bool)
    read[[r - 2 for r in ragged + blank]] = False
    if np.count_nonzero(read & ~np.isfinite(t)) > bad_time:  # NaN or inf written as numbers
        p.append(f"{where}: time column {time!r} has missing or non-numeric values.")
    ok = read & np.isfinite(t)
    line, tr = np.flatnonzero(ok) + 2, t[ok]
    if len(t) < 2:
        p.append(f"{where}: {len(t)} data rows; at least 2 are needed.")
    elif len(tr) >= 2:
        d = np.diff(tr)
        if np.any(d <= 0):
            k = int(np.argmax(d <= 0))
            p.append(
                f"{where}: time column {time!r} must increase; row {line[k + 1]} has "
                f"t = {tr[k + 1]:g} s after {tr[k]:g} s."
            )
        else:
            # Twelve significant digits: timestamps written as decimals of k·dt carry rounding
            # noise (0.030000000000001137) that would leak into models and FMUs' step sizes.
            dt = float(f"{np.median(d):.12g}")
            dev = np.abs(d - dt)
            if np.any(dev > dt_tol * dt) and ok.all():  # a row left out is a step of 2 dt
                k = int(np.argmax(dev))
                p.append(
                    f"{where}: sampling is not uniform: step {d[k]:g} s at row {line[k + 1]} "
                    f"differs from the median {dt:g} s by more than {dt_tol:.0%} (the tolerance)."
                )
    if p:
        return None, 0.0, p
    extra = {
        h: values[:, j]
        for h, j in idx.items()
        if h not in requested and np.all(np.isfinite(values[:, j]))
    }
    exp = Experiment(
        t=t,
        u=values[:, [idx[n] for n in inputs]] if inputs else np.zeros((len(t), 0)),
        y=values[:, [idx[n] for n in outputs]] if outputs else np.zeros((len(t), 0)),
        name=path.stem,
        extra=extra,
        units=file_units,
    )
    return exp, dt, []


#: Units of a time column and their length in seconds (the time is read in seconds).
TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0, "h": 3600.0}

#: A header cell with its unit: ``name [unit]``.
_UNIT_CELL = re.compile(r"^(?P<name>.*?)\s*\[(?P<unit>[^\[\]]*)\]$")


def split_header(cell: str) -> tuple[str, str]:
    """Column name and unit of a CSV header cell: ``"q1 [rad]"`` -> ``("q1", "rad")``.

    A cell without a bracketed unit at its end has the unit ``""`` (unknown).

    >>> split_header(" q1 [rad] "), split_header("T1"), split_header("t[s]")
    (('q1', 'rad'), ('T1', ''), ('t', 's'))
    """
    cell = cell.strip()
    m = _UNIT_CELL.match(cell)
    if m is None:
        return cell, ""
    return m.group("name").strip(), m.group("unit").strip()


def _unit_problem(unit: str) -> str | None:
    """Why ``unit`` cannot be a unit, or None."""
    if not isinstance(unit, str):
        return f"expected text, found {unit!r}."
    if not unit.isprintable() or any(c in unit for c in ",;\"'[]"):
        return f"{unit!r} has separators, brackets, quotes or control characters."
    if len(unit) > 40:
        return f"{unit[:40]!r}... is longer than 40 characters."
    return None


def write_csv(
    path: str | Path, columns: dict[str, FloatArray], units: Mapping[str, str] | None = None
) -> Path:
    """Write named columns (equal length) as CSV with full float precision.

    Columns with a unit in ``units`` get the header cell ``name [unit]`` (:func:`split_header`
    reads it back).

    Raises
    ------
    DataError
        A column name that a CSV header cannot hold unquoted (a separator, a quote, a control
        character, or an empty name).
    """
    path = Path(path)
    names = list(columns)
    bad = [n for n in names if not n or any(c in n for c in ",\"'") or not n.isprintable()]
    if bad:
        raise DataError(
            "Column names cannot be written to a CSV header (no separators, quotes or control "
            f"characters): {', '.join(repr(n) for n in bad)}."
        )
    units = {n: u for n, u in (units or {}).items() if u and n in columns}
    bad_units = [f"{n}: {why}" for n, u in units.items() if (why := _unit_problem(u))]
    if bad_units:
        raise DataError("Units cannot be written to a CSV header:", bad_units)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    cells = [f"{n} [{units[n]}]" if n in units else n for n in names]
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(cells) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.17g")
    return path
