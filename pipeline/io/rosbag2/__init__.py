"""ROS 2 bags: the bag reader (:mod:`.reader`) and one module per storage (:mod:`.storage_sqlite3`,
:mod:`.storage_mcap`), laid out as rosbags lays out its ``rosbag2`` package."""
