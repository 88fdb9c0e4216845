"""The 2D dam break's surge front from NumPy arrays (run from the repository's root)."""
import sys

import matplotlib

matplotlib.use("Agg")  # files only, no window
import matplotlib.pyplot as plt
import numpy as np
import pmpm

sim = pmpm.Simulation("examples/dam_break_2d.toml")
a = 0.05715  # the column's width (m)
times, fronts = [], []
for k in range(1, 41):
    sim.run(until=0.01 * k)  # to t = 0.01 k s, landing on it
    x = sim.particle_field("position")  # (n, 2), one row per particle
    times.append(sim.time * np.sqrt(2 * 9.81 / a))
    fronts.append(x[:, 0].max() / a)
plt.plot(times, fronts, "o-", label="pmpm, projection")
plt.xlabel("t sqrt(2g/a)")
plt.ylabel("front x / a")
plt.savefig(sys.argv[1] if len(sys.argv) > 1 else "front.png")
