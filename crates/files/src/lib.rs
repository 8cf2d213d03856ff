//! The file side of facepose's core, which does no I/O itself: the shared data's readers
//! ([`data`]) and model bundles on disk ([`store`]: atomic writes). The service's models
//! folder (versions, the `ACTIVE` pointer, job records) builds on [`store`].

pub mod data;
pub mod rendered;
pub mod store;
