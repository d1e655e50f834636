"""The background trainer: labels in, model versions and p(success) for every edge out.

The app's side of it:

    >>> from vgm_studio.trainer import TrainerSupervisor, request_training, trainer_status
    >>> supervisor = TrainerSupervisor(workspace, retrain_every=25)
    >>> supervisor.start()                  # the trainer process, restarted when it dies
    >>> trainer_status(store)               # idle / training epoch k of n / metrics / labels since
    >>> request_training(store)             # "Train now"
    >>> supervisor.stop()
"""

from vgm_studio.trainer.registry import (
    ModelRecord,
    TrainerStatus,
    active_version,
    list_models,
    register_model,
    request_training,
    trainer_status,
)
from vgm_studio.trainer.supervisor import TrainerSupervisor
from vgm_studio.trainer.watch import PromotionWatcher

__all__ = [
    "ModelRecord",
    "PromotionWatcher",
    "TrainerStatus",
    "TrainerSupervisor",
    "active_version",
    "list_models",
    "register_model",
    "request_training",
    "trainer_status",
]
