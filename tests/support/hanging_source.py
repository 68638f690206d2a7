"""A sample source whose first maker of one batch hangs forever without dying: a stuck sampler actor."""

from __future__ import annotations

import os
import time
from pathlib import Path

from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, Batch


class HangingSourceConfig(AnalyticSourceConfig):
    hang_at: int
    flag: str  # a file: the process that creates it hangs; the others make the batch as usual


class HangingSource(AnalyticSource):
    def batch(self, index: int) -> Batch:
        if index == self.config.hang_at:
            try:
                Path(self.config.flag).touch(exist_ok=False)
            except FileExistsError:
                pass
            else:
                Path(self.config.flag).write_text(str(os.getpid()))
                while True:
                    time.sleep(60)
        return super().batch(index)
