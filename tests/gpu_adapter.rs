//! Adapter choice: `GpuWhenAvailable` refuses software adapters unless allowed, `GpuRequired` takes them.

mod common;
use common::ecs::app_with;
use kinetrace::ecs::{GpuQueries, TraceConfig, TraceMode};
use kinetrace::gpu::{ALLOW_SOFTWARE_ENV, adapter_accepted, software_allowed};
use wgpu::{AdapterInfo, Backend, DeviceType};

#[test]
fn software_adapters_are_accepted_only_when_allowed() {
    let software = AdapterInfo::new(DeviceType::Cpu, Backend::Vulkan);
    assert!(!adapter_accepted(&software, false));
    assert!(adapter_accepted(&software, true));
    for hardware in [
        DeviceType::DiscreteGpu,
        DeviceType::IntegratedGpu,
        DeviceType::VirtualGpu,
        DeviceType::Other,
    ] {
        let info = AdapterInfo::new(hardware, Backend::Vulkan);
        assert!(adapter_accepted(&info, false), "{hardware:?}");
        assert!(adapter_accepted(&info, true), "{hardware:?}");
    }
}

#[test]
fn the_environment_allows_software_only_with_1() {
    assert!(!software_allowed(false, None));
    assert!(!software_allowed(false, Some("0")));
    assert!(!software_allowed(false, Some("")));
    assert!(!software_allowed(false, Some("yes")));
    assert!(software_allowed(false, Some("1")));
    assert!(software_allowed(true, None));
    assert!(software_allowed(true, Some("0")));
}

/// Whether the plugin built with `config` created a GPU context.
fn plugin_has_gpu(config: TraceConfig) -> bool {
    app_with(config).0.contains_resource::<GpuQueries>()
}

/// On this machine's adapter (lavapipe in CI: a software one), the plugin's modes choose as documented.
#[test]
fn plugin_modes_follow_the_adapter_rule() {
    let Some(gpu) = kinetrace::gpu::shared_for_tests() else {
        return;
    };
    let software = gpu.adapter_info().device_type == DeviceType::Cpu;
    let env_allows = std::env::var(ALLOW_SOFTWARE_ENV).is_ok_and(|v| v == "1");
    let mode = |mode, allow_software_gpu| TraceConfig {
        mode,
        allow_software_gpu,
        ..Default::default()
    };
    assert!(plugin_has_gpu(mode(TraceMode::GpuRequired, false)));
    assert!(plugin_has_gpu(mode(TraceMode::GpuWhenAvailable, true)));
    // Only the one adapter of this machine: refused when it is software and nothing allows it.
    assert_eq!(
        plugin_has_gpu(mode(TraceMode::GpuWhenAvailable, false)),
        !software || env_allows,
        "adapter {}",
        gpu.adapter_name()
    );
    assert!(!plugin_has_gpu(mode(TraceMode::Cpu, true)));
}
