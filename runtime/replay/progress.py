"""The progress bar of a long replay (tqdm, on stderr): reading a bag's messages, running the filter's events."""
from __future__ import annotations

from ..extras import require

#: below this many steps no bar is drawn
PROGRESS_STEPS = 2000


def progress_bar(total: int, enabled: bool, description: str, unit: str = "event"):
    """A tqdm bar over total steps, or None when disabled or short."""
    if not enabled or total < PROGRESS_STEPS:
        return None
    tqdm = require("tqdm", "the replay's progress bar", extra="replay").tqdm
    return tqdm(total=total, desc=description, unit=unit, leave=False)
