//! Points, the second stage of the data path: the points AO is traced at
//! and sent for, generated over each mesh's surface ([`generate`]: uniform
//! spawning, then weighted sample elimination, paper 3.1, and `gaps`
//! filled on strips thinner than the spacing; each point
//! anchored to its triangle so skinning carries it) and laid out in an
//! instance's grid ([`layout`], paper 3.2).

mod gaps;
pub(crate) mod generate;
pub(crate) mod layout;
