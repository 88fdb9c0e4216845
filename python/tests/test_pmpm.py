"""Tests of the Python package: the API against exact solutions, against the run directory
`pmpm.run` writes, and against VTK's own reader; the README's script and the sweep run.

Run from anywhere after `pip install ./python`: `python -m pytest python/tests`.
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import pmpm

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def short(example: str, end_time: float, **changes: object) -> dict:
    """An example deck as a dict, run to `end_time` with frames at its end only."""
    deck = pmpm.read_deck(EXAMPLES / example)
    changes = {"simulation.end_time": end_time, "output.interval": end_time, **changes}
    return pmpm.with_changes(deck, changes)


def test_hydrostatic_pressure_is_exact():
    # A column at rest under the projection: p = rho g (H - y) at every particle, to
    # round-off, from the first step (the example's header states it for every frame).
    sim = pmpm.Simulation(EXAMPLES / "hydrostatic_projection_2d.toml")
    sim.run(until=0.1)
    deck = sim.deck
    rho = deck["materials"][0]["density"]
    g = -deck["simulation"]["gravity"][1]
    top = deck["bodies"][0]["shape"]["max"][1]
    y = sim.particle_field("position")[:, 1]
    p = sim.particle_field("pressure")
    # the top particles sit h/4 below the body's top: H is the body's top
    exact = rho * g * (top - y)
    assert sim.steps == 20
    assert np.max(np.abs(p - exact)) < 1e-9 * rho * g * top


def test_in_memory_run_matches_the_run_directory(tmp_path):
    # Stepping in Python and `pmpm run` take the same steps: the last frame's particles
    # equal the in-memory fields to the CSV's 10 digits.
    deck = short("dam_break_2d.toml", 0.05)
    summary = pmpm.run(deck, tmp_path / "out", threads=2)
    sim = pmpm.Simulation(deck, threads=2)
    assert sim.run() == summary["steps"]
    assert sim.time == pytest.approx(0.05, abs=1e-12)
    with open(tmp_path / "out" / "frames" / "particles_000001.csv") as f:
        rows = list(csv.DictReader(f))
    frame = {k: np.array([float(r[k]) for r in rows]) for k in ("id", "x", "y", "vx", "pressure")}
    np.testing.assert_array_equal(frame["id"], sim.particle_field("id"))
    x = sim.particle_field("position")
    np.testing.assert_allclose(frame["x"], x[:, 0], rtol=1e-9)
    np.testing.assert_allclose(frame["y"], x[:, 1], rtol=1e-9)
    np.testing.assert_allclose(frame["vx"], sim.particle_field("velocity")[:, 0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(frame["pressure"], sim.particle_field("pressure"), rtol=1e-9, atol=1e-9)


def test_grid_fields_spread_the_particles():
    # Linear hat weights sum to 1: the nodes hold the particles' mass to round-off, and the
    # volume fraction of a node deep in the column is 1 within the particles' J.
    sim = pmpm.Simulation(short("dam_break_2d.toml", 0.02))
    sim.run()
    mass = sim.grid_field("mass")
    xs, ys = sim.grid_coordinates
    assert mass.shape == (len(xs), len(ys))
    assert mass.sum() == pytest.approx(sim.particle_field("mass").sum(), rel=1e-12)
    # node (i, j) is at (xs[i], ys[j]): a node in the column's middle is full, one far
    # downstream is empty
    inside = (np.searchsorted(xs, 0.02), np.searchsorted(ys, 0.05))
    assert sim.grid_field("volume_fraction")[inside] == pytest.approx(1.0, abs=0.01)
    assert mass[np.searchsorted(xs, 0.4), np.searchsorted(ys, 0.05)] == 0.0
    assert sim.grid_field("velocity").shape == mass.shape + (2,)
    assert sim.grid_field("stress").shape == mass.shape + (2, 2)
    for name in pmpm.Simulation.grid_fields:
        assert np.all(np.isfinite(sim.grid_field(name)))


def test_three_dimensions():
    sim = pmpm.Simulation(EXAMPLES / "dam_break_3d.toml")
    assert sim.dimension == 3
    dt = sim.step()
    assert dt > 0 and sim.time == pytest.approx(dt) and sim.steps == 1
    n = sim.particle_count
    assert sim.particle_field("position").shape == (n, 3)
    assert sim.particle_field("stress").shape == (n, 3, 3)
    assert sim.particle_field("material").dtype == np.uint16
    shape = tuple(len(c) for c in sim.grid_coordinates)
    assert len(shape) == 3
    assert sim.grid_field("pressure").shape == shape
    assert sim.grid_field("velocity").shape == shape + (3,)
    for name in pmpm.Simulation.particle_fields:
        assert len(sim.particle_field(name)) == n


def test_run_lands_on_the_time_asked_for():
    sim = pmpm.Simulation(EXAMPLES / "dam_break_2d.toml")
    sim.run(until=0.0123)
    assert sim.time == pytest.approx(0.0123, abs=1e-12)
    steps = sim.steps
    assert sim.run(until=0.0123) == 0 and sim.steps == steps
    assert sim.mass_balance() == 0.0


def test_running_to_many_times_keeps_the_water():
    # Landing on each of 40 times takes no sliver of a step (a projection step that short
    # turns the leftover divergence into a pressure spike): the volume stays within the
    # example's bound of 0.05 %, and 99 % of the particles within 1 % of their volume.
    sim = pmpm.Simulation(EXAMPLES / "dam_break_2d.toml", threads=2)
    v0 = sim.particle_field("volume").sum()
    for k in range(1, 41):
        sim.run(until=0.01 * k)
        assert sim.time == pytest.approx(0.01 * k, abs=1e-12)
        assert abs(sim.particle_field("volume").sum() / v0 - 1) < 5e-4
        assert np.percentile(sim.particle_field("jacobian"), 1) > 0.99


def test_errors_name_what_is_wrong():
    deck = pmpm.read_deck(EXAMPLES / "dam_break_2d.toml")
    with pytest.raises(pmpm.DeckError, match="grid.cell_size"):
        pmpm.Simulation(pmpm.with_changes(deck, {"grid.cell_size": -1.0}))
    with pytest.raises(pmpm.DeckError, match="viscosty"):
        pmpm.Simulation(pmpm.with_changes(deck, {"materials[0].viscosty": 1.0}))
    with pytest.raises(pmpm.DeckError):
        pmpm.Simulation(EXAMPLES / "no_such_deck.toml")
    with pytest.raises(TypeError, match="simulation.end_time"):
        pmpm.Simulation(pmpm.with_changes(deck, {"simulation.end_time": object()}))
    with pytest.raises(TypeError):
        pmpm.Simulation(3)
    sim = pmpm.Simulation(deck)
    with pytest.raises(KeyError, match="position"):
        sim.particle_field("positions")
    with pytest.raises(KeyError, match="pressure"):
        sim.grid_field("presure")
    with pytest.raises(ValueError):
        pmpm.Simulation(deck, threads=0)
    # NumPy numbers are taken as the numbers they are
    ok = pmpm.with_changes(deck, {"simulation.end_time": np.float64(0.01), "bodies[0].particles_per_cell": np.int64(2)})
    assert pmpm.Simulation(ok).end_time == 0.01


def test_with_changes_copies():
    deck = pmpm.read_deck(EXAMPLES / "dam_break_2d.toml")
    changed = pmpm.with_changes(deck, {"materials[0].viscosity": 0.5, "pressure.tolerance": 1e-9})
    assert changed["materials"][0]["viscosity"] == 0.5
    assert deck["materials"][0]["viscosity"] != 0.5
    assert changed["pressure"]["tolerance"] == 1e-9
    with pytest.raises(KeyError):
        pmpm.with_changes(deck, {"materials[3].viscosity": 0.5})


def test_readme_shows_the_example_script():
    script = (ROOT / "python" / "examples" / "dam_break_front.py").read_text()
    assert script in (ROOT / "README.md").read_text()


def test_readme_script_plots_the_front(tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "front.png"
    subprocess.run(
        [sys.executable, "python/examples/dam_break_front.py", str(png)], cwd=ROOT, check=True
    )
    assert png.stat().st_size > 1000


def test_sweep_run_out_falls_as_the_yield_stress_rises():
    out = subprocess.run(
        [sys.executable, "python/examples/yield_stress_sweep.py", "0.5"],
        cwd=ROOT, check=True, capture_output=True, text=True,
    ).stdout
    run_outs = [float(line.split("run-out ")[1].split(" m")[0]) for line in out.splitlines()]
    assert len(run_outs) == 3
    assert run_outs[0] > run_outs[1] > run_outs[2] > 0


def test_vtk_reads_the_grid_frame_as_grid_field(tmp_path):
    # VTK's own reader finds every field docs/deck.md names in a grid frame, and its
    # pressure is the array grid_field gives (VTK's order: x fastest).
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy  # type: ignore[import-not-found]

    deck = short("yield_block_slump_2d.toml", 0.05, **{"output.formats": ["grid"]})
    pmpm.run(deck, tmp_path / "out", threads=2)
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(str(tmp_path / "out" / "frames" / "grid_000001.vti"))
    reader.Update()
    image = reader.GetOutput()
    data = image.GetPointData()
    names = {data.GetArrayName(i) for i in range(data.GetNumberOfArrays())}
    assert set(pmpm.Simulation.grid_fields) <= names
    sim = pmpm.Simulation(deck, threads=2)
    sim.run()
    pressure = sim.grid_field("pressure")
    assert image.GetDimensions()[:2] == pressure.shape
    from_vtk = vtk_to_numpy(data.GetArray("pressure"))
    np.testing.assert_allclose(from_vtk, pressure.ravel(order="F"), rtol=1e-6, atol=1e-6)


# --- robustness: Ctrl-C, limits up front, deep and odd dicts, threads --------------------


def test_a_deeply_nested_dict_is_refused_naming_where():
    # 20,000 levels used to overflow the conversion's stack: SIGSEGV
    deck = pmpm.read_deck(EXAMPLES / "dam_break_2d.toml")
    deep: dict = {}
    node = deep
    for _ in range(20_000):
        node["a"] = {}
        node = node["a"]
    with pytest.raises(pmpm.DeckError, match=r"extra\.a\.a\.a.*nested more than 64 deep"):
        pmpm.Simulation({**deck, "extra": deep})
    looped: list = []
    looped.append(looped)
    with pytest.raises(pmpm.DeckError, match=r"grid\.size\[0\]\[0\].*nested"):
        pmpm.Simulation(pmpm.with_changes(deck, {"grid.size": looped}))


def test_values_errors_name_their_key_and_numpy_is_taken():
    deck = pmpm.read_deck(EXAMPLES / "dam_break_2d.toml")
    with pytest.raises(pmpm.DeckError, match=r"simulation\.dimension: integer 1180591620717411303424 out of range"):
        pmpm.Simulation(pmpm.with_changes(deck, {"simulation.dimension": 2**70}))
    with pytest.raises(pmpm.DeckError, match=r"materials\[0\]\.density: integer of 16610 bits out of range"):
        pmpm.Simulation(pmpm.with_changes(deck, {"materials[0].density": 10**5000}))
    # NumPy arrays and scalars mean the lists and numbers they hold
    changes = {
        "simulation.gravity": np.array([0.0, -9.81]),
        "grid.size": np.array([0.4572, 0.17145], dtype=np.float64),
        "bodies[0].shape.max": (np.float32(0.05715), np.array(0.1143)),
        "bodies[0].particles_per_cell": np.uint8(2),
        "simulation.end_time": np.float64(0.01),
    }
    sim = pmpm.Simulation(pmpm.with_changes(deck, changes))
    assert sim.deck["simulation"]["gravity"] == [0.0, -9.81]
    assert sim.deck["bodies"][0]["particles_per_cell"] == 2
    # what means neither is refused naming its key
    with pytest.raises(TypeError, match=r"grid\.size\[0\]: a complex cannot be written"):
        pmpm.Simulation(pmpm.with_changes(deck, {"grid.size": np.array([0.4572, 1j])}))
    with pytest.raises(pmpm.DeckError, match=r"grid\.size"):
        pmpm.Simulation(pmpm.with_changes(deck, {"grid.size": np.zeros((2, 2))}))


def test_a_deck_needing_too_many_steps_is_refused_up_front(tmp_path):
    # 4e14 steps used to start, and run for years; now refused as `pmpm run` refuses it
    deck = pmpm.with_changes(
        pmpm.read_deck(EXAMPLES / "dam_break_2d.toml"), {"simulation.dt": 1e-15, "simulation.cfl": None}
    )
    with pytest.raises(pmpm.DeckError, match=r"4\.000e14 steps .*allow_large=True"):
        pmpm.Simulation(deck)
    with pytest.raises(pmpm.DeckError, match="steps"):
        pmpm.run(deck, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    sim = pmpm.Simulation(deck, allow_large=True)
    assert sim.step() == pytest.approx(1e-15)
    # and so is a time to run to that needs them
    sim = pmpm.Simulation(EXAMPLES / "dam_break_2d.toml")
    with pytest.raises(ValueError, match=r"until: 1000000000: the run needs about .* steps"):
        sim.run(until=1e9)
    assert sim.steps == 0


def test_a_deck_larger_than_the_machine_is_refused_before_allocating(tmp_path):
    # h / 300: about 460 GB; refused at once, naming the memory and allow_large
    deck = pmpm.read_deck(EXAMPLES / "dam_break_2d.toml")
    huge = pmpm.with_changes(deck, {"grid.cell_size": deck["grid"]["cell_size"] / 300})
    start = time.monotonic()
    with pytest.raises(pmpm.DeckError, match=r"needs about [\d.]+ [GT]B of memory.*allow_large=True"):
        pmpm.Simulation(huge)
    with pytest.raises(pmpm.DeckError, match="of memory"):
        pmpm.run(huge, tmp_path / "out")
    assert time.monotonic() - start < 5.0
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS")
def test_a_deck_beyond_ulimit_v_is_refused_not_aborted():
    # 50 GB under a 4 GB address-space limit used to abort the interpreter (status 134)
    script = f"""
import resource, pmpm
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, resource.RLIM_INFINITY))
deck = pmpm.read_deck({str(EXAMPLES / "dam_break_2d.toml")!r})
deck = pmpm.with_changes(deck, {{"grid.cell_size": deck["grid"]["cell_size"] / 100}})
try:
    pmpm.Simulation(deck, threads=2)
except pmpm.DeckError as e:
    print(e)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "ulimit -v" in done.stdout and "allow_large=True" in done.stdout, done.stdout


def test_threads_beyond_the_limit_are_refused():
    # a million threads used to hang for minutes, starting them
    deck = EXAMPLES / "dam_break_2d.toml"
    with pytest.raises(ValueError, match=r"threads: 1000000: at most \d+"):
        pmpm.Simulation(deck, threads=10**6)
    with pytest.raises(ValueError, match="threads"):
        pmpm.run(deck, "unused", threads=10**6)


def interrupt_after(seconds: float) -> threading.Timer:
    """A timer that sends SIGINT to this process, as Ctrl-C does, after `seconds`.

    Python's own handler (KeyboardInterrupt) is put in place first: a process started in the
    background of a non-interactive shell (`cmd &`) inherits SIGINT ignored, and Python then
    leaves it ignored, so the signal would never reach pmpm's loop.
    """
    signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(seconds, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    return timer


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to itself")
def test_ctrl_c_stops_simulation_run_after_the_step_in_progress():
    # The signal used to be checked on a worker thread, where Python never runs its
    # handlers: Ctrl-C went unseen until the whole run was over (here about 40 s).
    sim = pmpm.Simulation(EXAMPLES / "dam_break_2d.toml", threads=2)
    timer = interrupt_after(1.0)
    start = time.monotonic()
    try:
        with pytest.raises(KeyboardInterrupt):
            sim.run(until=1.0)
    finally:
        timer.cancel()
    assert time.monotonic() - start < 4.0
    # stopped at a step, the simulation whole: a later run goes on from there
    steps, t = sim.steps, sim.time
    assert 0 < t < 1.0 and steps > 0
    sim.run(until=t + 0.01)
    assert sim.steps > steps
    assert sim.time == pytest.approx(t + 0.01, abs=1e-12)
    assert np.all(np.isfinite(sim.particle_field("velocity")))


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to itself")
def test_ctrl_c_stops_pmpm_run_with_a_checkpoint(tmp_path):
    # As `pmpm run` does: the step in progress finishes, a frame and a checkpoint are
    # written, and the message says so and how to go on (resume=).
    deck = pmpm.with_changes(pmpm.read_deck(EXAMPLES / "dam_break_2d.toml"), {"simulation.end_time": 1.0})
    timer = interrupt_after(1.0)
    start = time.monotonic()
    try:
        with pytest.raises(KeyboardInterrupt, match="checkpoint") as stopped:
            pmpm.run(deck, tmp_path / "out", threads=2)
    finally:
        timer.cancel()
    assert time.monotonic() - start < 4.0
    checkpoint = tmp_path / "out" / "checkpoint.bin"
    assert checkpoint.stat().st_size > 0
    # the message gives the call that goes on; here to 0.02 s past where it stopped
    message = str(stopped.value)
    assert f'resume="{checkpoint}"' in message, message
    t = float(message.split(", t = ")[1].split(" s")[0])
    summary = pmpm.run(pmpm.with_changes(deck, {"simulation.end_time": t + 0.02}), tmp_path / "out", threads=2, resume=checkpoint)
    assert summary["time"] == pytest.approx(t + 0.02, abs=1e-12)
