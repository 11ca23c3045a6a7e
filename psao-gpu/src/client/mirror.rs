//! A client's mirror on the GPU: the flat buffers `reconstruct.wgsl` reads
//! (per-instance parameters, every instance's bucket entries and point
//! words one after another, the normal table), uploaded whole when the set
//! of instances or their layout changes and by the changed ranges the
//! [`Mirror`] reports otherwise.

use psao_codec::{
    Change, GPU_RECORD_WORDS, InstanceDef, Mirror, gpu_instance_record, normal_table,
};

use crate::context::GpuContext;
use crate::error::GpuError;

/// `PsaoInstance` of `reconstruct.wgsl`: the words
/// [`gpu_instance_record`] computes (its documentation has the layout); an
/// all-zero record is an instance that cannot be sampled.
type InstanceGpu = [u32; GPU_RECORD_WORDS];

/// Where one instance's arrays start in the flat buffers.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Slot {
    def: InstanceDef,
    first_bucket: u32,
    first_word: u32,
}

/// The mirror's buffers on the device.
#[derive(Debug)]
pub struct GpuMirror {
    instances: wgpu::Buffer,
    buckets: wgpu::Buffer,
    words: wgpu::Buffer,
    normals: wgpu::Buffer,
    /// Per instance id, where its arrays are (None: not defined).
    slots: Vec<Option<Slot>>,
    /// Bytes uploaded by the last [`sync`](Self::sync).
    last_upload: u64,
    /// A failed upload left the buffers behind the mirror: the next sync
    /// uploads everything.
    needs_full: bool,
    /// Counts reallocations of the buffers (bind groups made from
    /// [`bind_entries`](Self::bind_entries) must be remade when it changes).
    generation: u64,
}

/// Largest instance id the GPU mirror indexes densely.
pub const MAX_GPU_INSTANCE_ID: u32 = 1 << 20;

impl GpuMirror {
    /// An upload of `mirror` as it is now (its change list is left alone).
    pub fn new(ctx: &GpuContext, mirror: &Mirror) -> Result<GpuMirror, GpuError> {
        let table: Vec<[f32; 4]> = normal_table()
            .iter()
            .map(|n| n.extend(0.0).to_array())
            .collect();
        let normals = ctx.checked("mirror upload", || {
            ctx.buffer_with(
                "psao-gpu normal table",
                bytemuck::cast_slice(&table),
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            )
        })?;
        let mut m = GpuMirror {
            instances: normals.clone(),
            buckets: normals.clone(),
            words: normals.clone(),
            normals,
            slots: Vec::new(),
            last_upload: 0,
            needs_full: false,
            generation: 0,
        };
        m.upload_all(ctx, mirror)?;
        Ok(m)
    }

    /// Brings the buffers up to `mirror` and clears its change list: the
    /// changed bucket and word ranges are written in place; a new, removed
    /// or redefined instance, or a change list that says everything may
    /// have changed, uploads everything again (and bumps
    /// [`generation`](Self::generation)). On an error the change list is
    /// kept and the next sync uploads everything. Returns the bytes
    /// written.
    pub fn sync(&mut self, ctx: &GpuContext, mirror: &mut Mirror) -> Result<u64, GpuError> {
        let changes = mirror.changes().clone();
        let layout_changed = changes.all
            || changes
                .items
                .iter()
                // A change that is not a range or a transform (a new or
                // removed instance, or one this version does not know).
                .any(|c| {
                    !matches!(
                        c,
                        Change::Buckets(..) | Change::Words(..) | Change::Transform(_)
                    )
                });
        if self.needs_full || layout_changed || self.layout_differs(mirror) {
            // The change list is kept until the upload succeeded.
            self.needs_full = true;
            self.upload_all(ctx, mirror)?;
            self.needs_full = false;
            mirror.clear_changes();
            return Ok(self.last_upload);
        }
        let mut bytes = 0u64;
        let mut transforms = false;
        ctx.checked("mirror update", || {
            for c in &changes.items {
                match *c {
                    Change::Buckets(id, ref r) => {
                        if let (Some(Some(slot)), Some(inst)) =
                            (self.slots.get(id as usize), mirror.instance(id))
                        {
                            let entries = &inst.buckets()[r.start as usize..r.end as usize];
                            let flat: Vec<[u32; 2]> =
                                entries.iter().map(|e| [e.key, e.cell]).collect();
                            let at = (slot.first_bucket as u64 + r.start as u64) * 8;
                            ctx.queue
                                .write_buffer(&self.buckets, at, bytemuck::cast_slice(&flat));
                            bytes += flat.len() as u64 * 8;
                        }
                    }
                    Change::Words(id, ref r) => {
                        if let (Some(Some(slot)), Some(inst)) =
                            (self.slots.get(id as usize), mirror.instance(id))
                        {
                            let words = &inst.words()[r.start as usize..r.end as usize];
                            let at = (slot.first_word as u64 + r.start as u64) * 4;
                            ctx.queue
                                .write_buffer(&self.words, at, bytemuck::cast_slice(words));
                            bytes += words.len() as u64 * 4;
                        }
                    }
                    Change::Transform(_) => transforms = true,
                    // Layout changes went the full-upload way above.
                    _ => {}
                }
            }
            if transforms {
                let table = self.instance_table(mirror);
                ctx.queue
                    .write_buffer(&self.instances, 0, bytemuck::cast_slice(&table));
                bytes += (table.len() * std::mem::size_of::<InstanceGpu>()) as u64;
            }
        })
        .inspect_err(|_| self.needs_full = true)?;
        mirror.clear_changes();
        self.last_upload = bytes;
        Ok(bytes)
    }

    /// Whether the mirror's instances or their definitions differ from the
    /// uploaded layout.
    fn layout_differs(&self, mirror: &Mirror) -> bool {
        let mut n = 0;
        for (id, inst) in mirror.instances() {
            n += 1;
            match self.slots.get(id as usize) {
                Some(Some(s)) if s.def == *inst.def() => {}
                _ => return true,
            }
        }
        n != self.slots.iter().flatten().count()
    }

    fn upload_all(&mut self, ctx: &GpuContext, mirror: &Mirror) -> Result<(), GpuError> {
        let max_id = mirror.instances().map(|(id, _)| id).max();
        if let Some(id) = max_id.filter(|&id| id >= MAX_GPU_INSTANCE_ID) {
            return Err(GpuError::Limits {
                what: "instance id",
                needed: id as u64,
                limit: MAX_GPU_INSTANCE_ID as u64 - 1,
            });
        }
        let count = max_id.map_or(0, |m| m as usize + 1);
        let mut slots = vec![None; count];
        let (mut buckets, mut words) = (Vec::<[u32; 2]>::new(), Vec::<u32>::new());
        for (id, inst) in mirror.instances() {
            slots[id as usize] = Some(Slot {
                def: *inst.def(),
                first_bucket: buckets.len() as u32,
                first_word: words.len() as u32,
            });
            buckets.extend(inst.buckets().iter().map(|e| [e.key, e.cell]));
            words.extend_from_slice(inst.words());
        }
        let limit = ctx.device.limits().max_storage_buffer_binding_size;
        for (what, len) in [
            ("bucket entry bytes", buckets.len() * 8),
            ("point word bytes", words.len() * 4),
        ] {
            if len as u64 > limit {
                return Err(GpuError::Limits {
                    what,
                    needed: len as u64,
                    limit,
                });
            }
        }
        let table_bytes = slots.len().max(1) as u64 * std::mem::size_of::<InstanceGpu>() as u64;
        if table_bytes > limit {
            return Err(GpuError::Limits {
                what: "bytes of the per-instance table (largest instance id + 1)",
                needed: table_bytes,
                limit,
            });
        }
        let table = Self::table_of(&slots, mirror);
        let (i, b, w) = ctx.checked("mirror upload", || {
            (
                ctx.buffer_with(
                    "psao-gpu instances",
                    bytemuck::cast_slice(&table),
                    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                ),
                ctx.buffer_with(
                    "psao-gpu buckets",
                    bytemuck::cast_slice(&buckets),
                    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                ),
                ctx.buffer_with(
                    "psao-gpu words",
                    bytemuck::cast_slice(&words),
                    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                ),
            )
        })?;
        // Only now, with the new buffers made, does the layout change.
        self.slots = slots;
        self.instances = i;
        self.buckets = b;
        self.words = w;
        self.generation += 1;
        self.last_upload = (table.len() * std::mem::size_of::<InstanceGpu>()
            + buckets.len() * 8
            + words.len() * 4) as u64;
        Ok(())
    }

    /// The per-instance parameters, indexed by instance id.
    fn instance_table(&self, mirror: &Mirror) -> Vec<InstanceGpu> {
        Self::table_of(&self.slots, mirror)
    }

    fn table_of(slots: &[Option<Slot>], mirror: &Mirror) -> Vec<InstanceGpu> {
        let mut table = vec![[0u32; GPU_RECORD_WORDS]; slots.len().max(1)];
        for (id, slot) in slots.iter().enumerate() {
            let (Some(slot), Some(inst)) = (slot, mirror.instance(id as u32)) else {
                continue;
            };
            table[id] = gpu_instance_record(inst, slot.first_bucket, slot.first_word);
        }
        table
    }

    /// Whether instance `id` is held in bind space (point format 1): its
    /// pixels are looked up by their bind-space position and normal.
    pub fn bind_space(&self, id: u32) -> bool {
        self.slots
            .get(id as usize)
            .and_then(|s| s.as_ref())
            .is_some_and(|s| s.def.bind_space())
    }

    /// Bytes written by the last upload or sync.
    pub fn last_upload_bytes(&self) -> u64 {
        self.last_upload
    }

    /// How many times the buffers were reallocated (a keyframe, a new or
    /// removed instance): bind groups made from
    /// [`bind_entries`](Self::bind_entries) must be remade when it changes.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The bind group entries of `reconstruct.wgsl`'s group (bindings 0-3).
    pub fn bind_entries(&self) -> [wgpu::BindGroupEntry<'_>; 4] {
        [
            wgpu::BindGroupEntry {
                binding: 0,
                resource: self.instances.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: self.buckets.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: self.words.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: self.normals.as_entire_binding(),
            },
        ]
    }
}
