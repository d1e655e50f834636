"""Stage 8: a SLAM run → a rerun recording, written headless (CI machines have no viewer)."""

from vgm_studio.recording.record import write_recording

__all__ = ["write_recording"]
