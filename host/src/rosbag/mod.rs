//! ROS 2 recordings in and out (issue 28): `msr import-bag` reads rosbag2 (MCAP or SQLite3) into a
//! dataset; `--mcap` on the session commands writes what a session saw and did as an MCAP file
//! that Foxglove opens and `ros2 bag play` plays.
pub mod import;
pub mod msgs;
pub mod read;
pub mod session;
pub mod write;
