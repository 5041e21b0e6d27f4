//! The create-info every 2D colour image of the tutorial starts from, shared with GL or not.

use ash::vk;

// ANCHOR: image_info
/// A 2D colour image: one mip level, one layer, one sample, in the driver's OPTIMAL layout. GL
/// can use an OPTIMAL image only because it is the same driver (chapter 02 checks the UUIDs) and
/// because it is told so (GL_OPTIMAL_TILING_EXT, chapter 03).
pub fn image_info<'a>(
    format: vk::Format,
    usage: vk::ImageUsageFlags,
    extent: vk::Extent2D,
) -> vk::ImageCreateInfo<'a> {
    vk::ImageCreateInfo::default()
        .image_type(vk::ImageType::TYPE_2D)
        .format(format)
        .extent(vk::Extent3D { width: extent.width, height: extent.height, depth: 1 })
        .mip_levels(1)
        .array_layers(1)
        .samples(vk::SampleCountFlags::TYPE_1)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(usage)
        .initial_layout(vk::ImageLayout::UNDEFINED)
}
// ANCHOR_END: image_info
