"""``python -m vgm_studio.trainer --workspace DIR``: the trainer process the app supervises."""

from vgm_studio.trainer.process import main

if __name__ == "__main__":
    main()
