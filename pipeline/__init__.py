"""auvid: from underwater-vehicle trial logs to identified, validated motion models."""

from __future__ import annotations

import time

__version__ = "0.1.0"
SCHEMA_VERSION = "1"
#: When this process first imported the package: a source file changed on disk after it may not be the code that
#: runs (pipeline.config.snapshot writes no snapshot then).
IMPORTED_NS = time.time_ns()
