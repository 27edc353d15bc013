"""Binary log readers: ``open_log(path)`` picks MCAP, ROS 1 bag or ROS 2 bag by content (CSV: pipeline.io.text)."""

from __future__ import annotations

from pipeline.io.base import LogReader, ReadResult, SalvageInfo, TopicData, TopicInfo
from pipeline.io.detect import open_log, sniff

__all__ = ["LogReader", "ReadResult", "SalvageInfo", "TopicData", "TopicInfo", "open_log", "sniff"]
