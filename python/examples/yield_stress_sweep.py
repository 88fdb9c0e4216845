"""A parameter sweep: the run-out of a Bingham mud block against its yield stress.

Reads examples/yield_block_slump_2d.toml once, changes the yield stress for each run, and
prints the front's run-out at the end (run from the repository's root; about 2 s a run).
A stiffer mud stops sooner: the run-out falls as the yield stress rises.
"""
import sys

import pmpm

deck = pmpm.read_deck("examples/yield_block_slump_2d.toml")
end_time = float(sys.argv[1]) if len(sys.argv) > 1 else None  # shorter runs for a test
for tau_y in (20.0, 30.0, 45.0):
    changes = {"materials[0].yield_stress": tau_y}
    if end_time is not None:
        changes["simulation.end_time"] = end_time
    sim = pmpm.Simulation(pmpm.with_changes(deck, changes))
    sim.run()
    x = sim.particle_field("position")[:, 0]
    # the block spans x = 0.4 to 0.6; a particle stands for h / 2 of material around it
    run_out = x.max() + sim.cell_size / 4 - 0.6
    print(f"yield_stress = {tau_y:5.1f} Pa: run-out {run_out:.3f} m after {sim.steps} steps")
