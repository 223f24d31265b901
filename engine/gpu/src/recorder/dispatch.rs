//! Recording kernel dispatches: the kernel's buffers bound by name, its
//! push constants, the barriers its declared accesses need, and a
//! timestamp pair around it when profiling.

use super::*;

impl<'a> Recorder<'a> {
    pub(super) fn descriptor_set(
        &mut self,
        layout: vk::DescriptorSetLayout,
    ) -> Result<vk::DescriptorSet> {
        if self.sets_left == 0 {
            let sizes = [vk::DescriptorPoolSize::default()
                .ty(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(SETS_PER_POOL * MAX_BINDINGS)];
            // SAFETY: valid create info; retired with the recorder.
            let pool = unsafe {
                self.dev.raw.create_descriptor_pool(
                    &vk::DescriptorPoolCreateInfo::default()
                        .max_sets(SETS_PER_POOL)
                        .pool_sizes(&sizes),
                    None,
                )
            }
            .vk("vkCreateDescriptorPool")?;
            self.dev.objects.created(ObjectKind::DescriptorPool);
            self.desc_pools.push(pool);
            self.sets_left = SETS_PER_POOL;
        }
        let layouts = [layout];
        // SAFETY: the pool has room (counted by `sets_left`).
        let set = unsafe {
            self.dev.raw.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(*self.desc_pools.last().unwrap())
                    .set_layouts(&layouts),
            )
        }
        .vk("vkAllocateDescriptorSets")?[0];
        self.sets_left -= 1;
        Ok(set)
    }

    /// Records one dispatch of `kernel` with `groups` workgroups, binding
    /// each of `buffers` to the kernel's binding of that name and `push` as
    /// push constants. The buffers struct and the push type are the
    /// kernel's own (`latentam_shaders::bind`), so a swapped or missing
    /// buffer does not compile.
    pub fn dispatch<P: bytemuck::Pod, S: BindingSet>(
        &mut self,
        kernel: &'static KernelDef<P, S>,
        groups: [u32; 3],
        buffers: S::Buffers<'a, Buffer>,
        push: &P,
    ) -> Result<()> {
        let buffers = S::in_order(&buffers);
        self.record_dispatch(
            &kernel.kernel,
            Groups::Direct(groups),
            &buffers,
            bytemuck::bytes_of(push),
        )
    }

    /// Records one dispatch of `kernel` whose workgroup counts the GPU
    /// reads when it runs: three u32 (x, y, z) at byte `offset` of `args`,
    /// written by earlier work in this recorder (which orders the two;
    /// across batches, as for any buffer, [`Self::wait_for`]). A count of 0
    /// dispatches nothing, so a kernel can decide on the GPU whether a later
    /// one runs, without a host round trip. The counts must stay within
    /// the device's `max_workgroup_count`.
    pub fn dispatch_indirect<P: bytemuck::Pod, S: BindingSet>(
        &mut self,
        kernel: &'static KernelDef<P, S>,
        args: &'a Buffer,
        offset: u64,
        buffers: S::Buffers<'a, Buffer>,
        push: &P,
    ) -> Result<()> {
        let buffers = S::in_order(&buffers);
        if !offset.is_multiple_of(4) {
            return Err(Error::bad_input(
                format!("kernel `{}`", kernel.kernel.name),
                format!("indirect arguments at byte {offset}, not a multiple of 4"),
            ));
        }
        args.ensure_bytes(offset + 12, "indirect dispatch arguments")?;
        if args.kind() != BufferKind::Device {
            return Err(Error::bad_input(
                format!("kernel `{}`", kernel.kernel.name),
                format!("indirect arguments in staging buffer `{}`", args.name()),
            ));
        }
        let written = buffers
            .iter()
            .zip(kernel.kernel.bindings)
            .any(|(b, decl)| decl.writable && b.raw == args.raw);
        if written {
            return Err(Error::bad_input(
                format!("kernel `{}`", kernel.kernel.name),
                format!(
                    "writes `{}`, which holds its own workgroup counts",
                    args.name()
                ),
            ));
        }
        self.record_dispatch(
            &kernel.kernel,
            Groups::Indirect(args, offset),
            &buffers,
            bytemuck::bytes_of(push),
        )
    }

    /// An indirect dispatch of a kernel known only by its declaration, with
    /// `buffers` in binding order: for building kernels ahead of use
    /// (`Context::warm_up_only`), which dispatches every kernel of the
    /// catalogue the same way.
    pub(crate) fn dispatch_untyped_indirect(
        &mut self,
        kernel: &'static Kernel,
        args: &'a Buffer,
        buffers: &[&'a Buffer],
    ) -> Result<()> {
        let push = vec![0u8; kernel.push_constant_size as usize];
        // It does no work (zero workgroups), stated so, so that no kernel
        // of the warm-up counts as a dispatch of unknown work.
        self.next_work = Some(latentam_shaders::Work::default());
        self.record_dispatch(kernel, Groups::Indirect(args, 0), buffers, &push)
    }

    /// States the work of the next dispatch recorded, for a kernel whose
    /// work its launch does not show (`// @cost caller`, e.g. the blending
    /// passes, which walk tile lists whose lengths only the binning knows)
    /// or to replace a launch-counted figure with a better one. It is
    /// counted in [`Context::gpu_work`] under that dispatch's kernel.
    pub fn work_of_next(&mut self, work: latentam_shaders::Work) {
        self.next_work = Some(work);
    }

    pub(super) fn record_dispatch(
        &mut self,
        k: &'static Kernel,
        groups: Groups<'a>,
        buffers: &[&'a Buffer],
        push: &[u8],
    ) -> Result<()> {
        // A stated work belongs to this dispatch whatever becomes of it.
        let stated = self.next_work.take();
        self.check_dispatch(k, groups, buffers)?;
        if matches!(groups, Groups::Direct(g) if g.contains(&0)) {
            return Ok(());
        }
        if let Some(missing) = self.dev.info.missing_for(k) {
            return Err(Error::Unsupported(format!(
                "kernel {} needs {missing}, which {} does not offer (or the options turned off)",
                k.name, self.dev.info.name
            )));
        }
        let pipe = self
            .dev
            .pipelines
            .get(&self.dev.raw, self.dev.pipeline_cache, k)?;
        let mut reads = Vec::new();
        let mut writes = Vec::new();
        if let Groups::Indirect(args, _) = groups {
            reads.push(args.raw);
        }
        for (b, decl) in buffers.iter().zip(k.bindings) {
            if decl.writable {
                writes.push(b.raw);
            } else {
                reads.push(b.raw);
            }
        }
        self.track(&reads, &writes);

        let set = if buffers.is_empty() {
            None
        } else {
            Some(self.bound_set(pipe.set_layout, buffers)?)
        };

        let start = self.timestamp(vk::PipelineStageFlags::COMPUTE_SHADER);
        // SAFETY: recording into our own command buffer with objects that
        // outlive the submission (pipeline cache, retired pools, borrowed
        // buffers).
        unsafe {
            let d = &self.dev.raw;
            d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, pipe.pipeline);
            if let Some(set) = set {
                d.cmd_bind_descriptor_sets(
                    self.cmd,
                    vk::PipelineBindPoint::COMPUTE,
                    pipe.layout,
                    0,
                    &[set],
                    &[],
                );
            }
            if k.push_constant_size > 0 {
                d.cmd_push_constants(
                    self.cmd,
                    pipe.layout,
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    push,
                );
            }
            match groups {
                Groups::Direct([x, y, z]) => d.cmd_dispatch(self.cmd, x, y, z),
                Groups::Indirect(args, offset) => {
                    d.cmd_dispatch_indirect(self.cmd, args.raw, offset)
                }
            }
        }
        self.dev.calls.dispatched();
        let direct = match groups {
            Groups::Direct(g) => Some(g),
            Groups::Indirect(..) => None,
        };
        let work = stated.or_else(|| k.work_of(push, direct));
        self.dev.work.recorded(k.name, work);
        let end = self.timestamp(vk::PipelineStageFlags::COMPUTE_SHADER);
        if let (Some(s), Some(e)) = (start, end) {
            self.labels.push((k.name, s, e));
        }
        Ok(())
    }

    /// Refuses a dispatch the kernel or the device cannot take.
    fn check_dispatch(
        &self,
        k: &'static Kernel,
        groups: Groups<'a>,
        buffers: &[&'a Buffer],
    ) -> Result<()> {
        if self.transfer {
            return Err(Error::bad_input(
                format!("kernel `{}`", k.name),
                "recorded on the transfer queue",
            ));
        }
        if buffers.len() != k.bindings.len() {
            return Err(Error::bad_input(
                format!("kernel `{}`", k.name),
                format!(
                    "takes {} buffers ({}), got {}",
                    k.bindings.len(),
                    k.bindings
                        .iter()
                        .map(|b| b.name)
                        .collect::<Vec<_>>()
                        .join(", "),
                    buffers.len()
                ),
            ));
        }
        if k.bindings.len() as u32 > MAX_BINDINGS {
            return Err(Error::Unsupported(format!(
                "kernel `{}` has more than {MAX_BINDINGS} bindings",
                k.name
            )));
        }
        let max = self.dev.info.max_workgroup_count;
        if let Groups::Direct(groups) = groups {
            if groups.iter().zip(max.iter()).any(|(g, m)| g > m) {
                return Err(Error::Unsupported(format!(
                    "kernel `{}`: {groups:?} workgroups exceed the device limit {max:?}",
                    k.name
                )));
            }
        }
        for b in buffers {
            if b.kind() != BufferKind::Device {
                return Err(Error::bad_input(
                    format!("kernel `{}`", k.name),
                    format!("`{}` is a staging buffer", b.name()),
                ));
            }
        }
        Ok(())
    }

    /// A fresh descriptor set of `layout` with `buffers[i]` at binding i.
    fn bound_set(
        &mut self,
        layout: vk::DescriptorSetLayout,
        buffers: &[&'a Buffer],
    ) -> Result<vk::DescriptorSet> {
        let set = self.descriptor_set(layout)?;
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|b| {
                [vk::DescriptorBufferInfo::default()
                    .buffer(b.raw)
                    .offset(0)
                    .range(vk::WHOLE_SIZE)]
            })
            .collect();
        let writes: Vec<vk::WriteDescriptorSet> = infos
            .iter()
            .enumerate()
            .map(|(i, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(i as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        // SAFETY: the set is fresh and not in use.
        unsafe { self.dev.raw.update_descriptor_sets(&writes, &[]) };
        Ok(set)
    }

    /// Dispatches `groups` workgroups along one logical dimension, split over
    /// x and y when it exceeds the x limit. Kernels recover the index with
    /// `linear_group()` and must ignore indices past their work.
    pub fn dispatch_linear<P: bytemuck::Pod, S: BindingSet>(
        &mut self,
        kernel: &'static KernelDef<P, S>,
        groups: u32,
        buffers: S::Buffers<'a, Buffer>,
        push: &P,
    ) -> Result<()> {
        let split = self.linear_groups(groups);
        self.dispatch(kernel, split, buffers, push)
    }

    /// How [`Self::dispatch_linear`] splits `groups` workgroups over x and
    /// y: the counts an indirect dispatch of such a kernel needs.
    pub fn linear_groups(&self, groups: u32) -> [u32; 3] {
        self.dev.info.linear_groups(groups)
    }
}
