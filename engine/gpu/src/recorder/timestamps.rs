//! Timestamp queries come from pools of a fixed size, taken as needed by
//! a recorder and read back with its submission.

use ash::vk;

/// Queries per pool.
pub(super) const QUERIES_PER_POOL: u32 = 512;

/// One query pool and how many of its queries a recorder has used.
pub(super) struct QueryBlock {
    pub(super) pool: vk::QueryPool,
    pub(super) used: u32,
}
