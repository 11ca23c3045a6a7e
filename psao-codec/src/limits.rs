//! Receiver limits: what a decoder accepts before any length field can
//! drive an allocation (spec/wire-format.md, "Limits").

/// Bounds a [`Decoder`](crate::Decoder) and [`Mirror`](crate::Mirror)
/// enforce. The defaults are the spec's; a session may negotiate others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest frame (header + payload as sent), bytes.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload, bytes.
    pub max_payload_bytes: u32,
    /// Most messages in one frame, `EndOfFrame` included.
    pub max_messages: u32,
    /// Most instances a mirror holds at once.
    pub max_instances: u32,
    /// Largest `table_log2` of an instance.
    pub max_table_log2: u8,
    /// Largest cell pool of an instance.
    pub max_cell_pool: u32,
    /// Largest total of bucket-entry and word bytes over all instances.
    pub max_mirror_bytes: u64,
}

impl Limits {
    /// Sets a limit by its field name (as used in spec/vectors and in
    /// configuration). Returns false, changing nothing, for an unknown name
    /// or a value that does not fit the field.
    pub fn set(&mut self, name: &str, value: u64) -> bool {
        let field = match name {
            "max_frame_bytes" => &mut self.max_frame_bytes,
            "max_payload_bytes" => &mut self.max_payload_bytes,
            "max_messages" => &mut self.max_messages,
            "max_instances" => &mut self.max_instances,
            "max_cell_pool" => &mut self.max_cell_pool,
            "max_table_log2" => {
                let Ok(v) = u8::try_from(value) else {
                    return false;
                };
                self.max_table_log2 = v;
                return true;
            }
            "max_mirror_bytes" => {
                self.max_mirror_bytes = value;
                return true;
            }
            _ => return false,
        };
        let Ok(v) = u32::try_from(value) else {
            return false;
        };
        *field = v;
        true
    }
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_frame_bytes: 64 << 20,
            max_payload_bytes: 64 << 20,
            max_messages: 1 << 20,
            max_instances: 65_536,
            max_table_log2: 22,
            max_cell_pool: 1 << 24,
            max_mirror_bytes: 1 << 30,
        }
    }
}
