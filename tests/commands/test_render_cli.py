"""`laplab render`: PNGs of the top-down view and of each sensor."""

import numpy as np
from PIL import Image

from laplab.cli import main


def test_render_writes_every_sensor_picture(tmp_path, capsys):
    code = main(["render", "--track", "oval", "--progress", "30", "--out", str(tmp_path),
                 "--sensor", "STEREO_CAMERAS", "--sensor", "FRONT_FACING_CAMERA", "--sensor", "LIDAR"])
    assert code == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["oval-30-camera-640x480.png", "oval-30-front_facing_camera-160x120.png", "oval-30-lidar.png",
                     "oval-30-stereo_cameras-left-160x120.png", "oval-30-stereo_cameras-right-160x120.png",
                     "oval-30-topdown.png"]
    front = np.asarray(Image.open(tmp_path / "oval-30-front_facing_camera-160x120.png"))
    assert front.shape == (120, 160) and front.std() > 10  # a real picture, not a blank frame
    assert np.asarray(Image.open(tmp_path / "oval-30-camera-640x480.png")).shape == (480, 640, 3)
    left = np.asarray(Image.open(tmp_path / "oval-30-stereo_cameras-left-160x120.png"))
    right = np.asarray(Image.open(tmp_path / "oval-30-stereo_cameras-right-160x120.png"))
    assert (left != right).any()  # the two cameras sit 6 cm apart
    assert str(tmp_path / "oval-30-topdown.png") in capsys.readouterr().out


def test_render_rejects_unknown_sensors_and_progress(tmp_path, capsys):
    assert main(["render", "--sensor", "RADAR", "--out", str(tmp_path)]) == 2
    assert "RADAR" in capsys.readouterr().err
    assert main(["render", "--progress", "140", "--out", str(tmp_path)]) == 2
