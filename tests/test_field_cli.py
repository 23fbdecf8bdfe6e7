"""The field's plots, CLI subcommands and benchmark table (behaviour only; no timings asserted)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from planbench.cli.field import add_commands
from planbench.field import KernelSpec, full_field
from planbench.field.bench import BenchSettings, format_table, run
from planbench.field.plots import parse_slice, plot_field_slice
from planbench.geometry.occupancy import OccupancyGrid


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="planbench")
    add_commands(p.add_subparsers(dest="command", required=True))
    return p


def is_png(path) -> bool:
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("profile", ["gaussian", "all"])
def test_kernel_command_writes_a_png(tmp_path, profile):
    out = tmp_path / "kernel.png"
    argv = ["kernel", "--profile", profile, "--reach", "0.05", "--out", str(out)]
    args = parser().parse_args(argv)
    assert args.func(args) == 0 and is_png(out)


def test_field_and_bench_commands_parse():
    args = parser().parse_args(["field", "--problem", "mbm:box/0001", "--slice", "z=0.3"])
    assert args.func.__name__ == "cmd_field" and args.resolution > 0
    args = parser().parse_args(["bench-field", "--quick"])
    assert args.func.__name__ == "cmd_bench" and args.quick


def test_slice_parsing():
    assert parse_slice("z=0.3") == (2, 0.3)
    assert parse_slice(" X = -1 ") == (0, -1.0)
    for bad in ("0.3", "w=1", "z=abc"):
        with pytest.raises(ValueError, match="axis=value"):
            parse_slice(bad)


def test_field_slice_plot(tmp_path):
    data = np.zeros((20, 20, 10))
    data[8:12, 8:12, 2:8] = 1.0
    grid = OccupancyGrid(data, [0.0, 0.0, 0.0], 0.02)
    field = full_field(grid, KernelSpec(reach=0.08).build(0.02))
    out = tmp_path / "field.png"
    plot_field_slice(grid, field, 2, 0.1, out=out, samples=40)
    assert is_png(out)


def test_benchmark_runs_and_prints_every_column():
    settings = BenchSettings(
        sizes=(12,), lengths=(5,), dtypes=("float32",), repeat=1, min_repeat=1, budget=0.0, points=4
    )
    rows = run(settings)
    assert len(rows) == 1
    t = rows[0].times
    assert {"full", "+margin", "scipy1d", "fft", "dense", "edt+grad", "lazy", "sample"} <= set(t)
    table = format_table(rows, 4)
    assert table.count("\n") == 2 and "12^3" in table and "edt/full" in table
