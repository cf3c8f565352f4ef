//! The board's pipeline. See the issue tracker (firmware issue) for the stage list.
#![cfg_attr(not(feature = "std"), no_std)]
