"""A notebook-style study with the Python API: run a small campaign, load its cells and episodes,
look at the unsafe ones, replay one, and compare with a second run.

Run it as a script from the repository root (about four minutes on 2 busy cores with the kernels
cached; the two runs land in ``results/``, or in ``$MCVERIFY_RESULTS`` when it is set):

    .venv/bin/pip install -e '.[pandas]'
    .venv/bin/python docs/example_notebook.py

Each block below is what a notebook cell would hold.
"""

import mcverify

# --- 1. Run: a campaign file with overrides, as `mcverify run ... --episodes 4 --set ...` would.
base = mcverify.run("campaigns/smoke.toml", episodes=4, workers=2, progress=False)
print("run folder:", base.path)

# --- 2. Per-cell statistics: one typed row per cell; the varied fields are columns named as in the file.
cells = base.cells(as_pandas=True)
columns = ["cell", "scenario.front_speed_kmh", "safe_k", "safe_n", "safe_low", "safe_high"]
print(cells[columns].to_string())  # to_string: the whole table, not "..."

# --- 3. Episodes: one row per episode (docs/metrics.md lists the columns); the grid values are
#        columns too (here scenario.front_speed_kmh), so episodes group without a join.
episodes = base.episodes(as_pandas=True)
stats = episodes.groupby("scenario.front_speed_kmh")[["min_dist_front_m", "overtake_time_s"]].agg(["min", "mean"])
print(stats.to_string())
unsafe = episodes[episodes["safe"] == False]  # noqa: E712 - a nullable column: error rows are neither
print(f"{len(unsafe)} unsafe episode(s)")

# --- 4. Replay one episode bit for bit (the first unsafe one if any): trajectory parquet and a plot.
episode_id = int(unsafe["episode_id"].iloc[0]) if len(unsafe) else 0
result = mcverify.replay(base.path, episode_id)
print("replayed:", result.trajectory_path, result.plot_path)

# --- 5. The same episodes with twice the perception noise, then a paired comparison.
noisy = mcverify.run("campaigns/smoke.toml", episodes=4, settings=["noise.scale=2"], workers=2, progress=False)
comparison = mcverify.compare(base.path, noisy.path)
for c in comparison["comparisons"]:
    safe = c["rates"]["safe"]
    print(c["cell_a"], "paired" if c["paired"] else "unpaired", f"safe-rate difference {safe['diff']:+.2f}",
          f"[{safe['low']:+.2f}, {safe['high']:+.2f}]")
