"""Evaluation videos: an MP4 that decodes to the expected frames, episodes unchanged by rendering,
and a clear error when offscreen rendering is impossible."""

import json

import pytest

from ahrm_stack.config import ConfigError, load_extra, VideoConfig
from ahrm_stack.env.video import RenderError, read_mp4, select_gl_backend
from ahrm_stack.evaluate import main
from ahrm_stack.evaluation import evaluate

SHORT = ["task.episode.duration=1"]  # 20 control steps of 0.05 s
SMALL = ["width=160", "height=120"]


def test_video_is_decodable_with_the_expected_frames(tmp_path):
    video = tmp_path / "scripted.mp4"
    result = evaluate(None, 2, out=tmp_path / "with", video_path=video, video_episodes=[1],
                      video_overrides=SMALL, quiet=True, overrides=SHORT)
    frames, (height, width), fps = read_mp4(video)
    # one frame per control step before each action, plus the final state: 20 + 1
    assert frames == result["video"]["frames"] == 21
    assert (height, width) == (120, 160)
    assert fps == pytest.approx(20.0)


def test_rendering_does_not_change_the_episodes(tmp_path):
    evaluate(None, 2, out=tmp_path / "plain", quiet=True, overrides=SHORT)
    evaluate(None, 2, out=tmp_path / "filmed", video_path=tmp_path / "v.mp4", video_episodes=[0, 1],
             video_overrides=SMALL, quiet=True, overrides=SHORT)
    assert (tmp_path / "plain" / "evaluation.csv").read_text() == (tmp_path / "filmed" / "evaluation.csv").read_text()
    assert json.loads((tmp_path / "filmed" / "evaluation.json").read_text())["video"]["frames"] == 42


def test_video_cli_errors_are_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--policy", "scripted", "--episodes", "1", "--video", str(tmp_path / "v.mp4"),
              "--video-episodes", "3"])
    assert exit_info.value.code == 2
    assert "--video-episodes [3] must be < --episodes (1)" in capsys.readouterr().err
    assert main(["--policy", "scripted", "--episodes", "1", "--out", str(tmp_path), "--video",
                 str(tmp_path / "v.mp4"), "--video-config", "camera=nope"]) == 2
    assert "video.camera: 'nope' is not a camera" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="video.width must be even"):
        load_extra(VideoConfig, "video", ["width=161"])


def test_unusable_backend_names_mujoco_gl_and_the_packages(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "no-such-backend")
    with pytest.raises(RenderError, match=r"MUJOCO_GL=no-such-backend.*libegl1 libegl-mesa0 libgl1-mesa-dri.*libosmesa6"):
        select_gl_backend(["egl"])
