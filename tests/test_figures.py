import matplotlib.image as mpimg
import numpy as np
import pandas as pd
import pytest

from dpsi.datapoint import Datapoint
from dpsi.effectors import ROUND
from dpsi.heightmap import height_map, heightmap_distance_mm
from dpsi.identification import COLUMNS
from dpsi.motions import Trajectory
from dpsi.losses import simulated_heightmap
from dpsi.parameters import IDENTIFIED, LOWER, NAMES, UPPER
from dpsi.reporting.figures import plot_heightmaps, plot_particles, plot_runs


def synthetic_runs(levels=(1, 2), iterations=5) -> pd.DataFrame:
    """2 losses × 2 datasets × 2 seeds per level, parameters in range, metrics decreasing, a few NaNs."""
    rng = np.random.default_rng(0)
    rows = []
    for level in levels:
        for loss in ("prt_emd", "pcd_cd"):
            for dataset in ("12-mix", "1-round"):
                for seed in (0, 1):
                    for k in range(iterations):
                        row = {c: rng.uniform(1.0, 10.0) for c in COLUMNS}
                        row.update({n: rng.uniform(LOWER[n], UPPER[n]) for n in NAMES})
                        row.update({"level": level, "loss": loss, "dataset": dataset, "seed": seed,
                                    "iteration": k})
                        row.update({c: 1000.0 / (k + 1) + rng.uniform(0, 50)
                                    for c in COLUMNS if c.startswith("val_")})
                        rows.append(row)
    runs = pd.DataFrame(rows)
    runs.loc[runs.index[3::17], ["val_prt_emd", "E"]] = np.nan
    return runs


def block(nx=8, ny=8, nz=5, spacing=0.004, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Particles (m) on a grid standing on z = 0.01 around x = y = 0.4."""
    grid = np.stack(np.meshgrid(*(np.arange(n) * spacing for n in (nx, ny, nz)), indexing="ij"), -1).reshape(-1, 3)
    return grid - grid.mean(axis=0) * (1, 1, 0) + np.array([0.4, 0.4, 0.01]) + offset


@pytest.fixture
def datapoint() -> Datapoint:
    before = block()
    after = block(nz=3, offset=(0.01, 0.0, 0.0))
    centre = np.array([0.4, 0.4])
    return Datapoint(id="synthetic", motion="poking-2", effector=ROUND, particles=before,
                     particle_volume=0.004 ** 3, trajectory=Trajectory(np.zeros((3, 3)), np.zeros(3)),
                     start=np.array([0.4, 0.4, 0.03]), table_z=0.01, pcd_target=after[::2], prt_target=after,
                     heightmap=height_map(after, centre, floor=0.01), centre_xy=centre)


def assert_figure(tmp_path, name, min_pixels=400):
    png, pdf = tmp_path / f"{name}.png", tmp_path / f"{name}.pdf"
    assert png.stat().st_size > 0 and pdf.stat().st_size > 0
    image = mpimg.imread(png)
    assert min(image.shape[:2]) >= min_pixels
    assert image[..., :3].var() > 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left


@pytest.mark.parametrize("level", [1, 2])
def test_plot_runs_writes_png_and_pdf(tmp_path, level):
    runs = synthetic_runs()
    fig = plot_runs(runs, level, tmp_path / "runs.png", tmp_path / "runs.pdf")
    assert_figure(tmp_path, "runs")
    # top-left panel: first dataset, validation PCD Chamfer; per loss two seed lines then the mean line
    ax = fig.axes[0]
    assert ax.get_title() == "12-mix"
    one = runs[(runs.level == level) & (runs.dataset == "12-mix") & (runs.loss == "prt_emd")]
    by_seed = one.pivot_table(index="iteration", columns="seed", values="val_pcd_cd")
    seed0, seed1, mean = ax.lines[:3]
    np.testing.assert_allclose(seed1.get_ydata(), by_seed[1])
    np.testing.assert_allclose(mean.get_ydata(), by_seed.mean(axis=1))
    assert mean.get_color() == "C0" and ax.lines[3].get_color() == "C1"  # the second loss
    assert len(fig.axes) == 2 * (5 + len(IDENTIFIED[level]))  # 2 datasets × (metrics + parameters)


def test_plot_runs_single_iteration_and_dataset(tmp_path):
    runs = synthetic_runs(levels=(1,), iterations=1)
    plot_runs(runs[runs["dataset"] == "1-round"], 1, tmp_path / "one.png", tmp_path / "one.pdf")
    assert_figure(tmp_path, "one")


def test_plot_runs_rejects_bad_tables(tmp_path):
    png, pdf = tmp_path / "r.png", tmp_path / "r.pdf"
    runs = synthetic_runs()
    with pytest.raises(ValueError, match="empty"):
        plot_runs(runs.iloc[:0], 1, png, pdf)
    with pytest.raises(ValueError, match="val_heightmap_mm"):
        plot_runs(runs.drop(columns="val_heightmap_mm"), 1, png, pdf)
    with pytest.raises(ValueError, match="mu_table"):
        plot_runs(runs.drop(columns="mu_table"), 2, png, pdf)
    with pytest.raises(ValueError, match="no rows of level 2"):
        plot_runs(runs[runs["level"] == 1], 2, png, pdf)
    with pytest.raises(ValueError, match="unknown level"):
        plot_runs(runs, 3, png, pdf)
    with pytest.raises(ValueError, match=r"\.pdf"):
        plot_runs(runs, 1, png, tmp_path / "r.png")
    assert not list(tmp_path.iterdir())


def test_plot_heightmaps_writes_png_and_pdf(tmp_path, datapoint):
    fig = plot_heightmaps(datapoint, datapoint.particles, tmp_path / "hm.png", tmp_path / "hm.pdf",
                          title="synthetic")
    assert_figure(tmp_path, "hm")
    sim = simulated_heightmap(datapoint.particles, datapoint.heightmap_target())
    real_mm, sim_mm = ((m - datapoint.table_z) * 1000 for m in (datapoint.heightmap, sim))
    shown = [ax.images[0].get_array() for ax in fig.axes[:3]]
    np.testing.assert_allclose(shown[0], real_mm.T)
    np.testing.assert_allclose(shown[1], sim_mm.T)
    np.testing.assert_allclose(shown[2], (sim_mm - real_mm).T)
    distance = heightmap_distance_mm(sim, datapoint.heightmap)
    assert distance > 1.0
    assert fig.get_suptitle() == f"synthetic\nheight-map distance {distance:.1f} mm"


def test_plot_particles_writes_png_and_pdf(tmp_path, datapoint):
    final = datapoint.prt_target + np.array([0.0, 0.002, 0.0])
    fig = plot_particles(datapoint, final, tmp_path / "prt.png", tmp_path / "prt.pdf", title="synthetic")
    assert_figure(tmp_path, "prt")
    for ax, (name, points) in zip(fig.axes, (("before", datapoint.particles), ("simulated after", final),
                                             ("target (PRT)", datapoint.prt_target))):
        assert ax.get_title() == f"{name} (n = {len(points)})"
        np.testing.assert_allclose(np.column_stack(ax.collections[0]._offsets3d), points * 1000)
        assert ax.get_zlim()[0] < points[:, 2].min() * 1000 and ax.get_zlim()[1] > points[:, 2].max() * 1000


@pytest.mark.parametrize("plot", [plot_heightmaps, plot_particles])
def test_outcome_plots_reject_bad_particles(tmp_path, datapoint, plot):
    with pytest.raises(ValueError, match="final particles"):
        plot(datapoint, np.zeros((4, 2)), tmp_path / "x.png", tmp_path / "x.pdf")
    with pytest.raises(ValueError, match="final particles: contains non-finite"):
        plot(datapoint, np.full((4, 3), np.nan), tmp_path / "x.png", tmp_path / "x.pdf")


def test_the_interval_figure_draws_each_quantity_s_bar_estimate_and_truth(tmp_path, monkeypatch):
    from dpsi.reporting import figures

    rows = []
    for seed, determined in ((0, True), (1, False)):
        for quantity, (low, estimate, high, truth) in {"E": (3e4, 4e4, 6e4, 5e4),
                                                      "yield_stress/E": (0.04, 0.05, 0.07, 0.05),
                                                      "yield_stress^1*E^-0.9": (1.0, 2.0, 3.0, 2.5)}.items():
            rows.append(dict(rung="R1", level=1, loss="prt_emd", dataset="1-round", seed=seed, quantity=quantity,
                             estimate=estimate, low=low, high=high, determined=determined, truth=truth))
    drawn = {}
    monkeypatch.setattr(figures, "save", lambda fig, png, pdf: drawn.update(fig=fig))
    figures.plot_intervals(pd.DataFrame(rows), tmp_path / "u.png", tmp_path / "u.pdf", "intervals")
    panels = {ax.get_title(): ax for ax in drawn["fig"].axes}
    assert set(panels) == {"$E$", "yield_stress/E"}  # the principal direction's name differs by run: no panel
    bars = [line for line in panels["$E$"].lines if len(line.get_xdata()) == 2]
    assert [list(b.get_xdata()) for b in bars] == [[3e4, 6e4]] * 2
    assert [b.get_linestyle() for b in bars] == ["-", ":"]  # determined solid, not determined dotted
    crosses = [line for line in panels["$E$"].lines if line.get_marker() == "x"]
    assert [list(c.get_xdata()) for c in crosses] == [[5e4]] * 2
    monkeypatch.undo()
    figures.plot_intervals(pd.DataFrame(rows), tmp_path / "u.png", tmp_path / "u.pdf", "intervals")
    assert_figure(tmp_path, "u", min_pixels=250)
