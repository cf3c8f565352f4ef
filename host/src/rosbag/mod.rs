//! ROS 2 recordings in and out: rosbag2 (MCAP or SQLite3) read into a dataset, and a session's
//! log (what it saw and did) written as an MCAP file that Foxglove opens and `ros2 bag play` plays.
pub mod import;
pub mod msgs;
pub mod read;
pub mod session;
pub mod write;
