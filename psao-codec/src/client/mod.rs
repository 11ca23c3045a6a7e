//! The client half: the [`Decoder`](crate::Decoder) that checks frames
//! and applies them whole or not at all to the [`Mirror`](crate::Mirror),
//! and the reconstruction of AO from the mirror on the CPU
//! ([`reconstruct_ao`](crate::reconstruct_ao), paper eq. 2-4), with the
//! optional test of candidates hidden from the view
//! ([`reconstruct_ao_seen`](crate::reconstruct_ao_seen)).

pub(crate) mod decoder;
pub(crate) mod gpu_record;
pub(crate) mod hidden;
pub(crate) mod mirror;
pub(crate) mod reconstruct;
