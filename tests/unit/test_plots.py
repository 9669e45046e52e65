"""What the figures must make visible: connected or not, at a glance."""
from __future__ import annotations

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from uav_flock_tools import plots  # noqa: E402


def test_the_fiedler_axis_sets_small_values_apart_from_zero_and_shades_disconnected_spans() -> None:
    t = np.arange(10) * 0.1
    lam2 = np.array([0.5, 0.5, 0.0, 0.0, 0.02, 0.02, 0.0, 0.0, 0.0, 0.02])
    fig, ax = plt.subplots()
    ax.plot(t, lam2)
    plots.fiedler_axis(ax, t, lam2)
    fig.canvas.draw()
    assert ax.get_yscale() == 'symlog'
    to_px = ax.transData.transform
    zero, small, large = (to_px((0.0, v))[1] for v in (0.0, 0.02, 0.5))
    assert small - zero > 0.5 * (large - zero), '0.02 stands well clear of 0 (on a linear axis it is 4 % of the way)'
    spans = [p for p in ax.patches if p.get_alpha() is not None]
    assert len(spans) == 2, 'one shaded span per disconnected stretch'
    labels = ax.get_legend_handles_labels()[1]
    assert 'λ2 = 0: disconnected' in labels and labels.count('disconnected span') == 1
    plt.close(fig)


def test_a_single_series_gets_no_legend_of_its_own(tmp_path) -> None:
    path = plots.time_series([('run', np.arange(5.0), np.ones(5))], 'R_c (%)', 'Coverage', tmp_path / 'c.png')
    assert path.stat().st_size > 1000
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1], label='one')
    plots.finish(ax, 'x', 'y', 'title')
    assert ax.get_legend() is None
    ax.plot([0, 1], [1, 0], label='two')
    plots.finish(ax, 'x', 'y', 'title')
    assert ax.get_legend() is not None
    plt.close(fig)


def test_the_legend_of_the_animation_reads_the_same_in_every_frame(tmp_path) -> None:
    """One palette for the whole GIF: what does not move (the legend under the axes) is the same pixels in
    every frame, where a palette of each frame's own shifted its swatches' colours from frame to frame."""
    import numpy as np
    from PIL import Image

    from uav_flock_tools import simrun
    s = simrun.load_scenario('paper').with_overrides(maps=60, duration=12.0)
    result, _ = simrun.simulate(s)
    simrun.write_run(result, tmp_path, '60 MAPs')
    with Image.open(tmp_path / 'formation.gif') as gif:
        frames = []
        for n in range(gif.n_frames):
            gif.seek(n)
            frames.append(np.asarray(gif.convert('RGB')))
    assert len(frames) == 13
    legend = slice(int(0.9 * frames[0].shape[0]), None)  # the bottom tenth: the legend, below the x axis label
    assert len(np.unique(frames[0][legend].reshape(-1, 3), axis=0)) > 5, 'the legend is drawn there'
    for n, f in enumerate(frames[1:], 1):
        assert np.array_equal(f[legend], frames[0][legend]), f'the legend of frame {n} differs from the first'


def test_a_map_lost_is_drawn_where_it_was_last_seen() -> None:
    # MAP 1 flies at t = 0 and 0.1 s and is gone at 0.2 s; MAP 0 flies throughout.
    traj = {'t': np.array([0.0, 0.0, 0.1, 0.1, 0.2]), 'id': np.array([0, 1, 0, 1, 0]),
            'x': np.array([0.0, 5.0, 0.0, 6.0, 0.0]), 'y': np.array([0.0, 1.0, 0.0, 2.0, 0.0])}
    assert plots.lost_at(traj, 0.1).shape == (0, 2)
    assert plots.lost_at(traj, 0.2).tolist() == [[6.0, 2.0]]


def test_an_interrupted_run_and_a_map_killed_by_hand_are_marked_on_its_pictures(tmp_path) -> None:
    """Every picture of a run cut short says so, and a hand kill is marked on the time axes as a failure is."""
    import dataclasses

    from uav_flock_tools import simrun
    s = simrun.load_scenario('paper').with_overrides(maps=6, duration=2.0)
    result, _ = simrun.simulate(s)
    cut = dataclasses.replace(result, metrics=result.metrics[:11], events=[(5, [2, 4], 'killed')],
                              trajectory=result.trajectory[result.trajectory[:, 0] <= 10])
    captured: dict = {}

    def figures(*args, **kwargs):
        captured['label'], captured['events'] = args[6], args[8]
        return []
    original, plots.run_figures = plots.run_figures, figures
    try:
        simrun.write_run(cut, tmp_path, '6 MAPs')
    finally:
        plots.run_figures = original
    assert captured['label'].endswith('interrupted at t = 1.0 s'), captured['label']
    assert (0.5, '2 MAPs killed') in captured['events'] and (1.0, 'run interrupted') in captured['events']


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 80))
def test_the_links_drawn_are_every_pair_within_r_once(seed: int, n: int) -> None:
    """One polyline, a NaN between links: its pieces are the pairs within r, each once."""
    q = np.random.default_rng(seed).uniform(0.0, 100.0, (n, 2))
    x, y = plots.links_within(q, 24.0)
    pieces = np.column_stack([x, y]).reshape(-1, 3, 2)
    assert np.isnan(pieces[:, 2]).all()
    drawn = {tuple(sorted((tuple(a), tuple(b)))) for a, b in pieces[:, :2]}
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    want = {tuple(sorted((tuple(q[i]), tuple(q[j])))) for i, j in zip(*np.nonzero(np.triu(d <= 24.0, 1)))}
    assert drawn == want and len(pieces) == len(want)
