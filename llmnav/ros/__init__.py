"""ROS 2 interchange: runs as MCAP files of standard ROS 2 messages, nav2 `map_server` maps as worlds.

`messages` builds the ROS 2 messages (rosbags' type store supplies the definitions and the CDR
serialiser), `export` turns a run folder into an MCAP file, `record` samples what the export needs while a
run drives, `mapimport` reads a nav2 map (YAML + PGM/PNG) into a scenario. The optional dependencies
(`pip install llmnav[ros]`) are imported only by the modules that write MCAP.
"""
