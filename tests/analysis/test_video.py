"""Videos and frames: exact states at frame times, GIFs, strips, the mp4 refusal, env frames and the batched grid."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from helpers import reference_actions
from PIL import Image

import fxc_env
from fxc_env import ReferencePolicy
from fxc_env.analysis import video
from fxc_env.analysis.video import (
    VideoOptions,
    absolute_positions,
    frame_times,
    states_at,
    video_frames,
    video_options,
    write_gif,
    write_video,
)
from fxc_env.cli.main import main
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.rendering import FRAME_SIZE, GRID_EPISODES, SceneRenderer, frame_size, tile_frames

SMALL = VideoOptions(fps=4, seconds=1.5, size=(192, 128))  # 6 frames


def gif_frames(path):
    with Image.open(path) as image:
        count, size = image.n_frames, image.size
        durations = []
        for index in range(count):
            image.seek(index)
            durations.append(image.info["duration"])
    return count, size, durations


# ------------------------------------------------------------------ exact states at any time
@pytest.mark.parametrize(
    ("scenario", "settings"),
    [
        ("paper_fig1", {}),
        ("paper_fig1", {"u_max": 3.0}),
        ("formation_hexagon", {"n_intervals": 30}),
        (
            None,
            {
                "agent_model": {"name": "integrator_chain", "order": 3},
                "n_agents": 4,
                "topology": "ring",
                "n_intervals": 12,
            },
        ),
    ],
)
def test_states_at_any_time_are_the_closed_form_curves(scenario, settings):
    trajectory = fxc_env.simulate("reference", scenario, points_per_interval=5, **settings)
    # At the sampling instants: the sampled states themselves.
    at_instants = states_at(trajectory, trajectory.times)
    np.testing.assert_array_equal(at_instants, trajectory.states)
    # Inside the intervals: simulate's dense curves (the same closed forms, evaluated per interval).
    dense = absolute_positions(trajectory, trajectory.dense_times, states_at(trajectory, trajectory.dense_times))
    scale = np.max(np.abs(trajectory.dense_x))
    np.testing.assert_allclose(dense, trajectory.dense_x, rtol=0, atol=1e-9 * scale)


def test_states_at_between_instants_solve_the_double_integrator():
    """Against an ODE solver (tests only): x'' = u with u affine on each interval, from the sampled state."""
    from scipy.integrate import solve_ivp

    trajectory = fxc_env.simulate("reference", "paper_fig1")
    k, fraction = 0, 0.37  # inside the paper's 12 s first interval
    t0, t1 = trajectory.times[k], trajectory.times[k + 1]
    t = t0 + fraction * (t1 - t0)
    u0, u1 = trajectory.u_start[k][:, 0], trajectory.u_end[k][:, 0]
    y0 = np.concatenate([trajectory.x[k][:, 0], trajectory.v[k][:, 0]])

    def rhs(s, y):
        n = len(u0)
        return np.concatenate([y[n:], u0 + (u1 - u0) * (s - t0) / (t1 - t0)])

    solved = solve_ivp(rhs, (t0, t), y0, rtol=1e-11, atol=1e-11).y[:, -1]
    exact = states_at(trajectory, [t])[0]
    np.testing.assert_allclose(exact[:, 0, 0], solved[:6], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(exact[:, 1, 0], solved[6:], rtol=1e-8, atol=1e-8)


def test_frame_times_are_uniform_from_zero_to_the_deadline():
    times = frame_times(20.0, VideoOptions(fps=15, seconds=8).n_frames)
    assert len(times) == 120 and times[0] == 0.0 and times[-1] == 20.0
    np.testing.assert_allclose(np.diff(times), 20.0 / 119, rtol=1e-12)


def test_states_at_refuses_times_outside_the_episode():
    trajectory = fxc_env.simulate("reference", "paper_fig1", n_intervals=5)
    with pytest.raises(ArgumentError, match=r"times: every time must lie in \[0, T_s\]"):
        states_at(trajectory, [20.5])


# ------------------------------------------------------------------ GIFs and strips
@pytest.mark.parametrize("scenario", ["paper_fig1", "random_20_planar"])  # 1-D and 2-D
def test_gif_has_the_frame_count_and_size_asked_for_and_moves(tmp_path, scenario):
    trajectory = fxc_env.simulate("reference", scenario, n_intervals=15)
    report = write_video(trajectory, tmp_path / "run.gif", SMALL, strip=tmp_path / "strip.png")
    count, size, durations = gif_frames(tmp_path / "run.gif")
    assert count == report.n_frames == SMALL.n_frames == 6
    assert size == SMALL.size
    assert durations[:-1] == [250] * 5 and durations[-1] == video.GIF_HOLD_MS  # 4 frames/s, then a hold
    with Image.open(tmp_path / "strip.png") as strip:
        width, height = SMALL.size
        assert strip.size == (5 * width + 4, height)  # five frames and four one-pixel gaps
    frames = list(video_frames(trajectory, SMALL))
    assert all(f.shape == (128, 192, 3) and f.dtype == np.uint8 for f in frames)
    assert all(not np.array_equal(a, b) for a, b in itertools.pairwise(frames))  # the picture changes


def test_one_dimensional_trails_grow_from_left_to_right():
    trajectory = fxc_env.simulate("reference", "paper_fig1", n_intervals=15)
    renderer = SceneRenderer(trajectory.config, (320, 200))
    times = trajectory.times
    x = trajectory.x
    for k in (1, 8, 15):
        renderer.draw(times[: k + 1], x[: k + 1], ratio=0.5, interval=k, graph=0, topology=trajectory.topology)
        for i, line in enumerate(renderer.lines):
            np.testing.assert_array_equal(line.get_xdata(), times[: k + 1])
            np.testing.assert_array_equal(line.get_ydata(), x[: k + 1, i, 0])
        np.testing.assert_array_equal(renderer.dots.get_offsets()[:, 0], times[k])


def test_a_frame_drawn_over_a_kept_background_equals_one_drawn_afresh():
    trajectory = fxc_env.simulate("reference", "random_20_planar", n_intervals=10)
    frames = list(video_frames(trajectory, SMALL))
    fresh = SceneRenderer(trajectory.config, SMALL.size)
    times = frame_times(trajectory.config.settling_time, SMALL.n_frames)
    curve = np.union1d(times, trajectory.times)
    positions = absolute_positions(trajectory, curve, states_at(trajectory, curve))
    limits = video.data_limits(positions)
    end = len(curve)
    ratio = float(trajectory.disagreement[-1] / trajectory.disagreement[0])  # the frame at T_s shows D(T_s)/D(0)
    last = fresh.draw(
        curve[:end], positions[:end], ratio=ratio, interval=10, graph=int(trajectory.graphs[-1]),
        topology=trajectory.topology, limits=limits,
    )  # fmt: skip
    np.testing.assert_array_equal(frames[-1], last)


def test_mp4_without_an_encoder_is_refused_naming_what_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(video, "mp4_encoder", lambda: None)
    code = main(["simulate", "--n-intervals", "4", "--out", str(tmp_path / "out"), "--video", str(tmp_path / "x.mp4")])
    assert code == 2
    error = capsys.readouterr().err
    assert "--video: writing .mp4 needs an encoder" in error and "pip install imageio-ffmpeg" in error
    assert not (tmp_path / "out").exists()  # refused before anything was run or written


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--video", "x.avi"], "--video: expected a file name ending in .gif or .mp4"),
        (["--frame-strip", "x.jpg"], "--frame-strip: expected a file name ending in .png"),
        (["--video", "x.gif", "--video-size", "640"], "--video-size: expected a frame size WIDTHxHEIGHT"),
        (["--video", "x.gif", "--video-fps", "0"], r"--video-fps: expected an integer in \[1, 60\]"),
        (["--video", "x.gif", "--video-seconds", "nan"], "--video-seconds: expected a finite number"),
        (["--video", "x.gif", "--video-fps", "60", "--video-seconds", "600"], "at most 5000 are drawn"),
    ],
)
def test_bad_video_flags_are_one_line_usage_errors(tmp_path, capsys, flags, message):
    paths = [str(tmp_path / f) if f.startswith("x.") else f for f in flags]
    assert main(["simulate", "--out", str(tmp_path / "out"), *paths]) == 2
    assert message.replace("\\", "") in capsys.readouterr().err.replace("\\", "")


def test_video_shape_flags_without_a_video_are_refused_not_ignored(tmp_path, capsys):
    assert main(["simulate", "--out", str(tmp_path / "out"), "--video-fps", "5", "--video-size", "320x200"]) == 2
    error = capsys.readouterr().err
    assert "--video-fps, --video-size: applies only with --video or --frame-strip" in error
    assert not (tmp_path / "out").exists()


def test_frame_size_reads_pairs_and_text():
    assert frame_size("size", "320x200") == (320, 200) == frame_size("size", (320, 200))
    for bad in ("320", "32x200", "320x200x3", (320.0, 200), (True, 200), "axb"):
        with pytest.raises(ArgumentError, match="size: expected a frame size"):
            frame_size("size", bad)


def test_video_options_name_the_flags():
    with pytest.raises(ArgumentError, match="--video-seconds"):
        video_options(10, -1.0, names=("--video-fps", "--video-seconds", "--video-size"))


@pytest.mark.slow
def test_fxc_simulate_writes_the_video_and_the_strip(tmp_path, capsys):
    gif, strip = tmp_path / "run.gif", tmp_path / "strip.png"
    flags = ["--video", str(gif), "--frame-strip", str(strip), "--video-fps", "5", "--video-seconds", "1"]
    argv = ["simulate", "--n-intervals", "8", "--out", str(tmp_path / "out"), *flags, "--video-size", "160x96"]
    assert main(argv) == 0
    count, size, _ = gif_frames(gif)
    assert (count, size) == (5, (160, 96))
    with Image.open(strip) as picture:
        assert picture.size == (5 * 160 + 4, 96)
    printed = capsys.readouterr().out
    assert "video: 5 frames of 160x96 px, uniform in t from 0 to T_s" in printed and "frames/s" in printed


# ------------------------------------------------------------------ env frames
def test_parallel_env_rgb_array_frames_record_like_record_video(tmp_path):
    """The RecordVideo loop: render() after reset and after every step, at metadata['render_fps']."""
    env = fxc_env.parallel_env(scenario="paper_fig1", render_mode="rgb_array", n_intervals=6)
    policy = ReferencePolicy(env)
    observations, _ = env.reset(seed=0)
    frames = [env.render()]
    while env.agents:
        observations, *_ = env.step(reference_actions(policy, observations))
        frames.append(env.render())
    width, height = FRAME_SIZE
    assert all(f.shape == (height, width, 3) and f.dtype == np.uint8 for f in frames)
    assert not np.array_equal(frames[0], frames[-1])
    count = write_gif(frames, tmp_path / "episode.gif", env.metadata["render_fps"])
    assert count == 7 == gif_frames(tmp_path / "episode.gif")[0]
    env.close()


def test_no_frame_work_on_the_step_path_without_a_render_mode():
    def refuse(*args, **kwargs):
        raise AssertionError("recorded a frame with render_mode=None")

    env = fxc_env.parallel_env(scenario="paper_fig1", n_intervals=4)
    venv = fxc_env.ConsensusVecEnv(2, scenario="paper_fig1", n_intervals=4)
    for front in (env, venv):
        front._view.record = refuse
    policy = ReferencePolicy(env)
    observations, _ = env.reset(seed=0)
    while env.agents:
        observations, *_ = env.step(reference_actions(policy, observations))
    obs = venv.reset()
    for _ in range(3):
        obs, *_ = venv.step(ReferencePolicy(venv)(obs))
    assert env._view.history == [] and venv._view.history == []


# ------------------------------------------------------------------ the batched grid
def test_tile_frames_lays_out_as_stable_baselines3():
    from stable_baselines3.common.vec_env.base_vec_env import tile_images

    frames = [np.full((4, 6, 3), 10 * (i + 1), dtype=np.uint8) for i in range(5)]
    ours, theirs = tile_frames(frames), tile_images(frames)
    assert ours.shape == theirs.shape == (3 * 4, 2 * 6, 3)  # ceil(sqrt(5)) = 3 rows, 2 columns
    filled = theirs.any(axis=-1)
    np.testing.assert_array_equal(ours[filled], theirs[filled])
    assert np.all(ours[~filled] == 255)  # the empty cell is white


@pytest.mark.parametrize("n_envs", [1, 3])
def test_vec_env_render_is_one_frame_per_episode_tiled(n_envs):
    venv = fxc_env.ConsensusVecEnv(n_envs, scenario="random_20_planar", n_intervals=6, render_mode="rgb_array")
    venv.seed(0)
    obs = venv.reset()
    for _ in range(2):
        obs, *_ = venv.step(ReferencePolicy(venv)(obs))
    grid = venv.render()
    width, height = FRAME_SIZE
    rows = int(np.ceil(np.sqrt(n_envs)))
    cols = int(np.ceil(n_envs / rows))
    assert grid.shape == (rows * height, cols * width, 3) and grid.dtype == np.uint8
    images = venv.get_images()
    assert len(images) == venv.num_envs
    episodes = [images[b * venv.n_agents] for b in range(n_envs)]
    for b, picture in enumerate(episodes):
        r, c = divmod(b, cols)
        np.testing.assert_array_equal(grid[r * height : (r + 1) * height, c * width : (c + 1) * width], picture)
    if n_envs > 1:
        assert not np.array_equal(episodes[0], episodes[1])  # different episodes, different pictures
    venv.close()


def test_vec_env_records_at_most_the_grid_episodes():
    venv = fxc_env.ConsensusVecEnv(
        GRID_EPISODES + 2, n_agents=3, topology="ring", n_intervals=3, render_mode="rgb_array"
    )
    venv.reset()
    assert venv._view.history[0][1].shape == (GRID_EPISODES, 3, 1)  # (episodes, agents, dim)


@pytest.mark.slow  # 32 frames
def test_vec_env_beyond_the_grid_episodes_gets_a_shared_blank_frame():
    venv = fxc_env.ConsensusVecEnv(
        GRID_EPISODES + 2, n_agents=3, topology="ring", n_intervals=3, render_mode="rgb_array"
    )
    venv.reset()
    images = venv.get_images()
    assert len(images) == venv.num_envs == (GRID_EPISODES + 2) * 3
    unrecorded = images[GRID_EPISODES * 3 :]
    assert all(image is unrecorded[0] for image in unrecorded)  # one shared "not recorded" frame
    assert unrecorded[0].shape == images[0].shape and not np.array_equal(unrecorded[0], images[0])
    assert venv.render().shape == (4 * FRAME_SIZE[1], 4 * FRAME_SIZE[0], 3)  # the 16 recorded episodes, 4 x 4


def test_mp4_frames_go_to_ffmpeg_as_raw_rgb(tmp_path, monkeypatch):
    """With an ffmpeg binary on PATH, every frame is piped as W x H x 3 bytes (a stand-in binary keeps them)."""
    fake = tmp_path / "ffmpeg"
    fake.write_text('#!/bin/sh\nfor last; do :; done\ncat > "$last"\n')
    fake.chmod(0o755)
    monkeypatch.setattr(video, "mp4_encoder", lambda: str(fake))
    trajectory = fxc_env.simulate("reference", "paper_fig1", n_intervals=5)
    report = write_video(trajectory, tmp_path / "run.mp4", SMALL)
    width, height = SMALL.size
    assert report.n_frames == 6
    assert (tmp_path / "run.mp4").stat().st_size == 6 * width * height * 3


# ------------------------------------------------------------------ the TorchRL env
def test_torch_env_render_tiles_its_episodes_and_follows_their_clocks():
    import torch
    from tensordict import TensorDict

    from fxc_env.envs.torch_env import ConsensusTorchEnv

    env = ConsensusTorchEnv(batch_size=3, scenario="random_20_planar", n_intervals=6, action_bound=0.25)
    with pytest.raises(RuntimeError, match=r"reset\(\)"):
        env.render()
    td = env.reset()
    first = env.render()
    width, height = FRAME_SIZE
    assert first.shape == (2 * height, 2 * width, 3) and first.dtype == np.uint8  # 3 episodes: 2 x 2
    for _ in range(2):
        td = env.step(env.rand_action(td))["next"]
        env.render()
    assert [len(trail) for trail in env._snapshots.trails] == [3, 3, 3]  # t_0, t_1, t_2
    assert not np.array_equal(env.render(), first)
    assert [len(trail) for trail in env._snapshots.trails] == [3, 3, 3]  # the same instant is not added twice
    env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, batch_size=[3]))
    env.render()
    assert [len(trail) for trail in env._snapshots.trails] == [3, 1, 3]  # episode 1 starts a new trail


def test_torch_env_frames_through_torchrl_pixel_render_transform():
    from torchrl.envs import TransformedEnv
    from torchrl.record import PixelRenderTransform

    from fxc_env.envs.torch_env import ConsensusTorchEnv

    env = TransformedEnv(
        ConsensusTorchEnv(batch_size=2, scenario="paper_fig1", n_intervals=4), PixelRenderTransform(out_keys=["pixels"])
    )
    rollout = env.rollout(4)
    frames = rollout["next", "pixels"]
    assert len(frames) == 2  # one per episode of the batch (the same tiled picture)
    assert np.asarray(frames[0][-1]).shape == (2 * FRAME_SIZE[1], FRAME_SIZE[0], 3)  # 2 episodes, one above the other
