"""The robomaker-format training log a laplab training writes (logs/training/<time>-robomaker.log) is
read by the installed deepracer-utils: its SIM_TRACE_LOG parser gives the same steps as the simtrace
CSVs, and DeepRacerLog.load_robomaker_logs finds the hyperparameters, action space, sensors and
network in it."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torch", reason="a training run needs torch")
pytest.importorskip("pandas")
logs = pytest.importorskip("deepracer.logs")

from deepracer.logs import DeepRacerLog, LogFolderType  # noqa: E402
from deepracer.logs.handler import FSFileHandler  # noqa: E402
from deepracer.logs.log_utils import SimulationLogsIO  # noqa: E402

from laplab.env.metadata import ModelMetadata  # noqa: E402
from laplab.store.layout import model_folder  # noqa: E402
from laplab.store.robomaker_log import episode_lines, header_lines, robomaker_log_path  # noqa: E402
from laplab.train.config import TrainConfig  # noqa: E402
from laplab.train.jobs import create_training  # noqa: E402

EPISODES_PER_ITERATION = 4


class RobomakerLogHandler(FSFileHandler):
    """deepracer-utils' documented way to point DeepRacerLog at a log of one's own: a file handler
    that says 'console model with logs' and names the training robomaker log."""

    def __init__(self, model_root, log_path):
        super().__init__(str(model_root))
        self.log_path = str(log_path)

    def determine_root_folder_type(self):
        self.type = LogFolderType.CONSOLE_MODEL_WITH_LOGS
        self.training_robomaker_log_path = self.log_path
        return self.type


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A STATE model trained for 3 iterations of 4 episodes (discrete PPO)."""
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("home")
        patch.setenv("LAPLAB_HOME", str(root))
        config = TrainConfig()
        config = replace(config, hyperparameters={**config.hyper().to_dict(), "batch_size": 32, "num_epochs": 3,
                                                  "num_episodes_between_training": EPISODES_PER_ITERATION},
                         model_metadata=ModelMetadata().to_dict(), max_time_s=120, max_episodes=12, eval_episodes=1)
        create_training("robo", config).run()
        yield model_folder("robo")


def test_one_log_per_job_in_logs_training(trained):
    found = sorted((trained.root / "logs" / "training").glob("*-robomaker.log"))
    assert len(found) == 1 and re.fullmatch(r"[0-9]{14}-robomaker\.log", found[0].name)


def test_deepracer_utils_reads_the_steps_of_the_simtrace(trained):
    path = next((trained.root / "logs" / "training").glob("*-robomaker.log"))
    from_log = SimulationLogsIO.convert_to_pandas(SimulationLogsIO.load_data(str(path)), EPISODES_PER_ITERATION)
    csv = DeepRacerLog(str(trained.root))
    csv.load_training_trace()
    from_csv = csv.dataframe()
    assert len(from_log) == len(from_csv) > 0
    from_log = from_log.sort_values(["episode", "steps"], kind="stable").reset_index(drop=True)
    from_csv = from_csv.sort_values(["episode", "steps"], kind="stable").reset_index(drop=True)
    columns = ["iteration", "episode", "steps", "x", "y", "yaw", "steering_angle", "speed", "action", "reward",
               "done", "on_track", "progress", "closest_waypoint", "track_len", "tstamp", "episode_status",
               "pause_duration"]
    for column in columns:
        a, b = from_log[column].to_numpy(), from_csv[column].to_numpy()
        if a.dtype.kind == "f":
            assert np.allclose(a, b, rtol=0, atol=1e-9), column
        else:
            assert np.array_equal(a, b), column  # the same text: the same values
    # rows carry no wall clock in training: each writer stamps 'now' (the log a few ms after the CSV)
    assert np.abs(from_log["wall_clock"].to_numpy() - from_csv["wall_clock"].to_numpy()).max() < 60
    assert sorted(set(from_log["iteration"])) == [0, 1, 2]


def test_deepracer_log_loads_the_robomaker_log(trained):
    path = next((trained.root / "logs" / "training").glob("*-robomaker.log"))
    log = DeepRacerLog(filehandler=RobomakerLogHandler(trained.root, path))
    log.load_robomaker_logs()
    assert log.hyperparameters() == trained.read_hyperparameters()
    metadata = trained.read_model_metadata()
    assert log.action_space() == metadata["action_space"]
    agent = log.agent_and_network()
    assert agent["sensor_list"] == metadata["sensor"] and agent["network"] == metadata["neural_network"]
    assert agent["world"] == TrainConfig().track
    assert log.dataframe()["episode"].nunique() == 12


def test_episode_and_policy_training_lines(trained):
    text = next((trained.root / "logs" / "training").glob("*-robomaker.log")).read_text()
    training = re.findall(r"^Training> Name=main_level/agent, Worker=0, Episode=(\d+), Total reward=(-?[\d.e+-]+), "
                          r"Steps=(\d+), Training iteration=(\d+)$", text, re.M)
    assert [int(e) for e, *_ in training] == list(range(1, 13))
    assert [int(i) for *_, i in training] == [0] * 4 + [1] * 4 + [2] * 4
    steps = [int(s) for _, _, s, _ in training]
    assert steps == sorted(steps) and steps[0] > 0
    assert len(re.findall(r"^Policy training> Surrogate loss=\S+, KL divergence=\S+, Entropy=\S+, training epoch=0, "
                          r"learning_rate=\S+$", text, re.M)) == 3
    assert len(re.findall(r"^Testing> ", text, re.M)) == 3  # one evaluation lap per iteration


def test_header_and_lines_are_pure_functions(tmp_path):
    header = header_lines({"lr": 0.0003, "batch_size": 64}, {"sensor": ["LIDAR", "FRONT_FACING_CAMERA"],
                                                              "neural_network": "DEEP_CONVOLUTIONAL_NETWORK",
                                                              "action_space": [{"steering_angle": 0, "speed": 1}]},
                          "reInvent2019_track")
    assert "Sensor list ['LIDAR', 'FRONT_FACING_CAMERA'], network DEEP_CONVOLUTIONAL_NETWORK, simapp_version" in header
    assert "training_algorithm clipped_ppo, action_space_type discrete\n" in header
    assert ' * /WORLD_NAME: reInvent2019_track\n' in header and '\n  "batch_size": 64,\n' in header
    assert json.loads(header.split("hyper-parameters\n")[1].split("Loaded")[0]) == {"lr": 0.0003, "batch_size": 64}
    assert episode_lines("Training", 5, np.array([1.234]), np.array([10]), 100, 1) == \
        "Training> Name=main_level/agent, Worker=0, Episode=5, Total reward=1.23, Steps=110, Training iteration=1\n"
    first = robomaker_log_path(tmp_path, when=0)
    assert first.name == "19700101000000-robomaker.log"
    first.parent.mkdir(parents=True)
    first.write_text("x")
    assert robomaker_log_path(tmp_path, when=0).name == "19700101000001-robomaker.log"
