"""Robot settings shipped with planbench: one TOML file per robot (see ``planbench.robot``)."""

from pathlib import Path

ROBOTS_DIR = Path(__file__).resolve().parent
