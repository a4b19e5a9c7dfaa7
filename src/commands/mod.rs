//! The commands of the CLI besides `run` (which is [`crate::stages`]), one module each.

pub mod compare;
pub mod dem;
pub mod demo;
pub mod export;
pub mod features;
pub mod fiducials;
pub mod info;
pub mod init;
