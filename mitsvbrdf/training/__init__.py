"""Training: configs (:mod:`.config`), stages (:mod:`.stages`) and the driver (:mod:`.trainer`).

    mitsvbrdf train train/stage1-small.toml [--resume | --overwrite] [--set train.steps=10] [--out DIR]
    torchrun --nproc_per_node=2 -m mitsvbrdf train train/stage1.toml
"""

from .config import Config, ConfigError, load_config
from .stages import STAGES, RenderSettings, TrainingStage
from .trainer import Trainer, TrainingError, TrainingInterrupted, train

__all__ = ["Config", "ConfigError", "load_config", "STAGES", "RenderSettings", "TrainingStage", "Trainer",
           "TrainingError", "TrainingInterrupted", "train"]
