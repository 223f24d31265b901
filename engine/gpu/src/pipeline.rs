//! Compute pipelines, created on first use and cached per kernel. The one
//! binding convention: set 0, binding i = storage buffer i; scalars in push
//! constants.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use ash::vk;
use latentam_shaders::Kernel;

use latentam_base::{Error, Result, VkContext};

/// A kernel's pipeline and layouts. Owned by the context's cache and destroyed
/// with the device.
pub(crate) struct Pipeline {
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    pub set_layout: vk::DescriptorSetLayout,
    module: vk::ShaderModule,
}

#[derive(Default)]
pub(crate) struct PipelineCache {
    map: Mutex<HashMap<&'static str, Arc<Pipeline>>>,
    /// Kernels the driver failed to build, with its result: asked again,
    /// they fail at once instead of compiling again (a driver can take
    /// many seconds before it gives up on one).
    failed: Mutex<HashMap<&'static str, vk::Result>>,
    /// Kernels treated as rejected (`ContextOptions::rejected_kernels`).
    rejected: Vec<String>,
}

impl PipelineCache {
    /// A cache whose `rejected` kernels fail to build as if the driver
    /// rejected them.
    pub fn rejecting(rejected: Vec<String>) -> Self {
        Self {
            rejected,
            ..Self::default()
        }
    }

    /// `k`'s pipeline, created now if it was not yet. Creation runs outside
    /// the cache's locks, so threads build different kernels at once
    /// (`Context::warm_up_only`); two threads racing for the same kernel
    /// keep the first one stored and destroy the other, never used.
    pub fn get(
        &self,
        dev: &ash::Device,
        cache: vk::PipelineCache,
        k: &'static Kernel,
    ) -> Result<Arc<Pipeline>> {
        if let Some(p) = self.lock_map().get(k.name) {
            return Ok(p.clone());
        }
        if let Some(&result) = self.lock_failed().get(k.name) {
            return Err(Error::KernelBuild {
                kernel: k.name,
                result,
            });
        }
        let created = if self.rejected.iter().any(|r| r == k.name) {
            Err(Error::KernelBuild {
                kernel: k.name,
                result: vk::Result::ERROR_UNKNOWN,
            })
        } else {
            create(dev, cache, k)
        };
        match created {
            Ok(p) => {
                let mut map = self.lock_map();
                if let Some(first) = map.get(k.name) {
                    // SAFETY: `p` was never handed out, so nothing uses it.
                    unsafe { destroy(dev, &p) };
                    return Ok(first.clone());
                }
                let p = Arc::new(p);
                map.insert(k.name, p.clone());
                Ok(p)
            }
            Err(e) => {
                if let Error::KernelBuild { result, .. } = e {
                    if self.lock_failed().insert(k.name, result).is_none() {
                        log::warn!(
                            "the driver cannot build kernel {} ({result}); where it has another \
                             variant (a column-layout blending kernel) the engine uses that",
                            k.name
                        );
                    }
                }
                Err(e)
            }
        }
    }

    fn lock_map(&self) -> std::sync::MutexGuard<'_, HashMap<&'static str, Arc<Pipeline>>> {
        self.map.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn lock_failed(&self) -> std::sync::MutexGuard<'_, HashMap<&'static str, vk::Result>> {
        self.failed.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether the driver builds `k` (see `Context::kernel_builds`).
    pub fn builds(
        &self,
        dev: &ash::Device,
        cache: vk::PipelineCache,
        k: &'static Kernel,
    ) -> Result<bool> {
        match self.get(dev, cache, k) {
            Ok(_) => Ok(true),
            Err(Error::KernelBuild { .. }) => Ok(false),
            Err(e) => Err(e),
        }
    }

    /// The kernels the driver failed to build so far, with its results.
    pub fn failures(&self) -> Vec<(&'static str, vk::Result)> {
        let failed = self.failed.lock().unwrap_or_else(|p| p.into_inner());
        let mut v: Vec<_> = failed.iter().map(|(k, r)| (*k, *r)).collect();
        v.sort();
        v
    }

    /// The kernels whose pipelines exist.
    pub fn built(&self) -> Vec<&'static str> {
        self.lock_map().keys().copied().collect()
    }

    /// Pipelines created so far.
    pub fn len(&self) -> usize {
        self.map.lock().unwrap_or_else(|p| p.into_inner()).len()
    }

    pub fn destroy_all(&self, dev: &ash::Device) {
        let mut map = self.map.lock().unwrap_or_else(|p| p.into_inner());
        for (_, p) in map.drain() {
            // SAFETY: called from `Device::drop` after the GPU is idle.
            unsafe { destroy(dev, &p) };
        }
    }
}

unsafe fn destroy(dev: &ash::Device, p: &Pipeline) {
    // SAFETY: caller guarantees the GPU no longer uses these objects.
    unsafe {
        dev.destroy_pipeline(p.pipeline, None);
        dev.destroy_pipeline_layout(p.layout, None);
        dev.destroy_descriptor_set_layout(p.set_layout, None);
        dev.destroy_shader_module(p.module, None);
    }
}

fn create(dev: &ash::Device, cache: vk::PipelineCache, k: &'static Kernel) -> Result<Pipeline> {
    let bindings: Vec<vk::DescriptorSetLayoutBinding> = (0..k.bindings.len() as u32)
        .map(|i| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(i)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::COMPUTE)
        })
        .collect();
    // SAFETY: all create infos below are fully initialised; objects created
    // so far are destroyed if a later step fails.
    unsafe {
        let set_layout = dev
            .create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings),
                None,
            )
            .vk("vkCreateDescriptorSetLayout")?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(k.push_constant_size)];
        let set_layouts = [set_layout];
        let mut li = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if k.push_constant_size > 0 {
            li = li.push_constant_ranges(&ranges);
        }
        let layout = match dev.create_pipeline_layout(&li, None) {
            Ok(l) => l,
            Err(e) => {
                dev.destroy_descriptor_set_layout(set_layout, None);
                return Err(e).vk("vkCreatePipelineLayout");
            }
        };
        let module = match dev
            .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(k.spirv), None)
        {
            Ok(m) => m,
            Err(e) => {
                dev.destroy_pipeline_layout(layout, None);
                dev.destroy_descriptor_set_layout(set_layout, None);
                return Err(kernel_build(k, e, "vkCreateShaderModule"));
            }
        };
        let entry = std::ffi::CString::new(k.entry_point()).expect("kernel names have no NUL");
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(&entry);
        let ci = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout)];
        let pipeline = match dev.create_compute_pipelines(cache, &ci, None) {
            Ok(p) => p[0],
            Err((_, e)) => {
                dev.destroy_shader_module(module, None);
                dev.destroy_pipeline_layout(layout, None);
                dev.destroy_descriptor_set_layout(set_layout, None);
                return Err(kernel_build(k, e, "vkCreateComputePipelines"));
            }
        };
        Ok(Pipeline {
            pipeline,
            layout,
            set_layout,
            module,
        })
    }
}

/// A failed module or pipeline creation names its kernel; a lost device
/// and exhausted memory keep the errors every Vulkan call maps them to
/// ([`VkContext`]), which callers act on.
fn kernel_build(k: &Kernel, result: vk::Result, call: &'static str) -> Error {
    match Err::<(), _>(result).vk(call) {
        Err(Error::Vulkan { result, .. }) => Error::KernelBuild {
            kernel: k.name,
            result,
        },
        Err(other) => other,
        Ok(()) => unreachable!("an error stays an error"),
    }
}
