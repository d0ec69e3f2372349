"""Fuzzing the CLI with broken CSV files and model JSON (issue 15): never a traceback or a hang.

Hypothesis mutates a valid CSV file and a valid model file (seeded: ``derandomize``), and each
case runs ``tendonkit simulate`` / ``compare`` in-process with a 20 s alarm.  Every case must end
with exit status 2 and one message, or exit 0 with finite output of the right length; the inputs
stay byte-identical and a failed command leaves no file behind.
"""

from __future__ import annotations

import contextlib
import json
import signal
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tendonkit.cli import main
from tendonkit.dataset import Dataset, write_csv
from tendonkit.testsystems import random_state_space, simulate_truth

N_ROWS = 120


@contextlib.contextmanager
def alarm(seconds: int) -> Iterator[None]:
    def hang(signum: int, frame: object) -> None:
        raise TimeoutError(f"the command ran for more than {seconds} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory) -> tuple[str, str]:
    """A CSV file and an ARX model identified on it (texts)."""
    folder = tmp_path_factory.mktemp("valid")
    truth = random_state_space(2, 2, 2, seed=11, dt=0.05)
    data, _ = simulate_truth(truth, N_ROWS, noise=0.01, seed=3)
    e = data.experiments[0]
    csv = write_csv(
        folder / "d.csv",
        {"t": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1], "y1": e.y[:, 0], "y2": e.y[:, 1]},
    )
    model = folder / "m.json"
    code = main(
        [
            "identify", str(csv), "--inputs", "u1,u2", "--outputs", "y1,y2",
            "--option", "na=2", "--option", "nb=2", "-o", str(model),
        ]
    )  # fmt: skip
    assert code == 0
    return csv.read_text(), model.read_text()


def run_case(
    csv_text: str, model_text: str, capsys: pytest.CaptureFixture[str]
) -> list[tuple[int, int | None]]:
    """Both commands on the files; each one's exit status and, for ``simulate`` that ran, the
    number of rows it wrote."""
    results: list[tuple[int, int | None]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        csv, model, out = folder / "d.csv", folder / "m.json", folder / "out.csv"
        csv.write_bytes(csv_text.encode("utf-8", "surrogatepass"))
        model.write_text(model_text, encoding="utf-8")
        before = {p: p.read_bytes() for p in (csv, model)}
        for args in (
            ["simulate", str(model), str(csv), "-o", str(out)],
            ["compare", str(csv), str(model)],
        ):
            try:
                with alarm(20):
                    code = main(args)
            except SystemExit as exc:  # argparse's own usage errors
                code = int(exc.code or 0)
            err = capsys.readouterr().err
            assert code in (0, 2), (args, code, err)
            assert "Traceback" not in err
            if code == 2:
                assert err.startswith(("tendonkit: error:", "usage:")), err
            rows = None
            if args[0] == "simulate":
                if code == 0:
                    y = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
                    assert np.all(np.isfinite(y)) and y.shape[1] == 3
                    # one row per sample of the inputs the command read
                    names = [s["name"] for s in json.loads(model_text)["inputs"]]
                    read = Dataset.from_csv(csv, names, [], require_outputs=False)
                    assert y.shape[0] == read.experiments[0].n_samples, (y.shape, args)
                    rows = int(y.shape[0])
                    out.unlink()
                else:
                    assert not out.exists()
            results.append((code, rows))
        assert {p: p.read_bytes() for p in (csv, model)} == before
        assert sorted(p.name for p in folder.iterdir()) == ["d.csv", "m.json"]
    return results


JUNK = st.sampled_from(
    [",", ";", "\t", "\n", "\n\n", "\x00", "nan", "inf", "1e400", "-", "é", '"', " ", "0x1F",
     "t", "u1", "1e300", "", "\r\n"]
)  # fmt: skip


@st.composite
def csv_mutation(draw: st.DrawFn, text: str) -> str:
    lines = text.splitlines(keepends=True)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["insert", "delete", "dup", "truncate", "swap"]))
        i = draw(st.integers(0, len(lines) - 1))
        if kind == "insert":
            line = lines[i]
            j = draw(st.integers(0, len(line)))
            lines[i] = line[:j] + draw(JUNK) + line[j:]
        elif kind == "delete" and len(lines) > 1:
            lines.pop(i)
        elif kind == "dup":
            lines.insert(i, lines[i])
        elif kind == "truncate":
            lines = lines[: i + 1]
            lines[-1] = lines[-1][: draw(st.integers(0, len(lines[-1])))]
        elif kind == "swap" and len(lines) > 2:
            k = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[k] = lines[k], lines[i]
    return "".join(lines)


JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(10**30), max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=6,
)


def _paths(node: object, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def model_mutation(draw: st.DrawFn, text: str) -> str:
    data = json.loads(text)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(data) if p]
        path = draw(st.sampled_from(paths))
        node = data
        for key in path[:-1]:
            node = node[key]
        if draw(st.booleans()):
            node[path[-1]] = draw(JSON_VALUES)
        elif isinstance(node, dict):
            del node[path[-1]]
        else:
            node.pop(path[-1])
    return json.dumps(data)


FUZZ = settings(
    max_examples=120,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@FUZZ
@given(data=st.data())
def test_broken_csv_files(valid_files, capsys, data):
    csv_text, model_text = valid_files
    run_case(data.draw(csv_mutation(csv_text)), model_text, capsys)


@FUZZ
@given(data=st.data())
def test_broken_model_files(valid_files, capsys, data):
    csv_text, model_text = valid_files
    run_case(csv_text, data.draw(model_mutation(model_text)), capsys)


def test_the_valid_files_pass(valid_files, capsys):
    # both commands succeed on the unmutated files, and simulate writes every sample
    assert run_case(*valid_files, capsys) == [(0, N_ROWS), (0, None)]
