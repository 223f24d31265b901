//! The mapper's tests that span its parts (each part's own are beside
//! it): the stages of a keyframe, a frame's route, saved states.

pub(crate) mod fixtures;
mod persist_files;
mod persist_mutations;
mod route;
mod stages;
mod warm_up;
