//! The server half (feature `server`): acceleration structures built from
//! a scene, point AO traced with ray queries, the comparison with what
//! clients hold, and the pipeline backend. Needs a device with ray queries
//! ([`GpuContext::SERVER_FEATURES`](crate::GpuContext::SERVER_FEATURES)).

pub(crate) mod accel;
pub(crate) mod alpha;
pub(crate) mod ao;
pub(crate) mod backend;
