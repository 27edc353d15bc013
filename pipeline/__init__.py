"""auvid: from underwater-vehicle trial logs to identified, validated motion models."""

from __future__ import annotations

__version__ = "0.1.0"
SCHEMA_VERSION = "1"
