//! Every struct a Vulkan shader reads (push constants, a buffer's records) is declared twice:
//! once in GLSL and once in Rust. This checks the Rust side against the compiled SPIR-V itself,
//! member by member: the same names in the same order, at the same byte offsets, of the same
//! sizes, adding up to the same size. Reorder, rename, add or drop a member on either side and
//! the check names the first member that differs.
//!
//! The SPIR-V keeps its block and member names because `xtask` compiles with `glslc -g` and then
//! drops only the source text and line numbers (`-O` alone strips the names too).
//!
//! The Rust side is written with [`rust_block!`]; the SPIR-V side is read with the `spirq` crate,
//! built only for the tests (feature `reflect`), never for the chapters.

/// One member of a block: its name, byte offset and size.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    pub name: String,
    pub offset: usize,
    pub size: usize,
}

/// The members of a `#[repr(C)]` struct, in declaration order, and its size:
/// `rust_block!(AoRays { samples, accumulated, radius, scene_scale })`. Every field must be
/// named, in order: a field left out does not compile (the pattern is exhaustive), and one out of
/// order is caught by its offset.
#[macro_export]
#[doc(hidden)]
macro_rules! __rust_block {
    ($ty:ident { $($field:ident),* $(,)? }) => {{
        let value: $ty = ::bytemuck::Zeroable::zeroed();
        #[allow(unused_variables)]
        let $ty { $($field),* } = value;
        let members = vec![$($crate::base::shader_block::Member {
            name: stringify!($field).to_string(),
            offset: ::core::mem::offset_of!($ty, $field),
            size: ::core::mem::size_of_val(&value.$field),
        }),*];
        (members, ::core::mem::size_of::<$ty>())
    }};
}
#[doc(inline)]
pub use __rust_block as rust_block;

/// Checks `rust` (from [`rust_block!`]) against the struct named `block` in `spirv`: a push
/// constant block, a descriptor's buffer, or a struct reached through a buffer reference. Panics
/// naming the first difference; for a unit test.
#[cfg(any(test, feature = "reflect"))]
pub fn assert_matches_spirv(spirv: &[u8], block: &str, (rust, size): (Vec<Member>, usize)) {
    let shader = match reflect(spirv, block) {
        Ok(members) => members,
        Err(problem) => panic!("{problem}"),
    };
    for (i, (ours, theirs)) in rust.iter().zip(&shader.0).enumerate() {
        assert_eq!(ours, theirs, "member {i} of {block}: Rust has {ours:?}, the shader {theirs:?}");
    }
    assert_eq!(
        rust.len(),
        shader.0.len(),
        "{block} has {} members in Rust, {} in the shader: {rust:?} against {:?}",
        rust.len(),
        shader.0.len(),
        shader.0
    );
    assert_eq!(size, shader.1, "{block} is {size} bytes in Rust, {} in the shader", shader.1);
}

/// The members of the struct named `block` in `spirv`, and where its last member ends. Any struct
/// type of the module counts, also one no variable has (a buffer reference's, such as `Cameras`
/// in `temporal_ao.rgen`, reached only by casting an address). A GLSL struct used both in a
/// buffer and as a local variable is two SPIR-V types of one name; the one with offsets is read.
#[cfg(any(test, feature = "reflect"))]
pub fn reflect(spirv: &[u8], block: &str) -> Result<(Vec<Member>, usize), String> {
    use spirq::ty::Type;
    let mut found = None;
    // The inspector sees the module's type registry once every type is declared.
    spirq::ReflectConfig::new()
        .spv(spirv)
        .ref_all_rscs(true)
        .reflect_inspect_by(|module, _| {
            if found.is_none() {
                found = module.ty_reg.iter().find_map(|(_, ty)| match ty {
                    Type::Struct(s)
                        if s.name() == Some(block) && s.members.iter().all(|m| m.offset.is_some()) =>
                    {
                        Some(s.clone())
                    }
                    _ => None,
                });
            }
        })
        .map_err(|e| format!("cannot reflect the SPIR-V: {e}"))?;
    let found =
        found.ok_or_else(|| format!("no struct named {block} in the SPIR-V (compiled without -g?)"))?;
    let mut members = Vec::new();
    for (i, m) in found.members.iter().enumerate() {
        let name = m.name.clone().ok_or_else(|| format!("member {i} of {block} has no name"))?;
        let offset = m.offset.expect("found with every offset");
        let size = m.ty.nbyte().or(m.ty.min_nbyte()).ok_or_else(|| format!("{block}.{name} has no size"))?;
        members.push(Member { name, offset, size });
    }
    let end = members.last().map_or(0, |m| m.offset + m.size);
    Ok((members, end))
}
