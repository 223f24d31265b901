//! Tests of the Vulkan layer itself: lifetimes, accounting, profiling,
//! synchronisation and argument checks, one file per subject.

use latentam_shaders::{push, SCAN_BLOCKS};

use super::testing::{with_context, with_options};
use super::*;
use crate::ops::PrefixScan;
use latentam_shaders::bind;

mod checks;
mod lifetimes;
mod profiling;
mod rows;
mod synchronisation;
