//! The crate's one error type.

/// Everything a caller or an input file can get wrong. Returned, never panicked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} is not finite: {value:?}")]
    NonFiniteVertex {
        /// Index of the offending vertex in the position array.
        vertex: usize,
        /// Its coordinates.
        value: [f32; 3],
    },
    /// An index refers to a vertex that does not exist.
    #[error(
        "index {position} of the index buffer is {index}, but there are only {vertex_count} vertices"
    )]
    IndexOutOfRange {
        /// Position of the bad entry in the index array.
        position: usize,
        /// Its value.
        index: u32,
        /// Number of vertices.
        vertex_count: usize,
    },
    /// The index array does not describe whole triangles.
    #[error("index count {count} is not a multiple of 3 (the last {} indices form no triangle)", count % 3)]
    IndexCountNotMultipleOfThree {
        /// Length of the index array.
        count: usize,
    },
    /// More triangles than a [`Node`](crate::bvh::Node) can address.
    #[error("{count} triangles exceed the limit of {max} per BVH")]
    TooManyPrimitives {
        /// Triangles asked for.
        count: usize,
        /// The limit, [`MAX_PRIMITIVES`](crate::bvh::MAX_PRIMITIVES).
        max: usize,
    },
    /// A primitive box given to [`Bvh::build`](crate::bvh::Bvh::build) is empty or not finite.
    #[error("bounds of primitive {primitive} are empty or not finite")]
    NonFiniteBounds {
        /// Position of the box in the input.
        primitive: usize,
    },
    /// [`Bvh::validate`](crate::bvh::Bvh::validate) found a broken invariant.
    #[error("invalid tree: {0}")]
    InvalidTree(String),
    /// New vertex positions for a refit do not match the mesh the tree was built for.
    #[error("refit got {got} vertices, but the tree was built over {expected}")]
    VertexCountMismatch {
        /// Vertices the tree was built with.
        expected: usize,
        /// Vertices passed now.
        got: usize,
    },
    /// No GPU adapter could be found (or a device could not be created on it). Callers fall back to the CPU.
    #[error("no usable GPU: {0}")]
    NoGpu(String),
    /// The GPU reported an error while running kernels (validation, out of memory, lost device).
    #[error("GPU error: {0}")]
    Gpu(String),
    /// A glTF file could not be used; the message names the element (mesh, accessor, animation...).
    #[error("glTF: {0}")]
    Gltf(String),
    /// A file could not be read.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A transform given to a query is not finite or cannot be inverted (a zero scale, say).
    #[error("transform is not finite or not invertible: {0}")]
    InvalidTransform(String),
    /// A build option is out of its range.
    #[error("invalid build option: {0}")]
    InvalidOption(String),
    /// A GPU task pool run asked for more tasks than the pool holds (`capacity`); make a larger pool.
    #[error("task pool full: {asked} tasks asked for, the pool holds {capacity}")]
    TaskPoolFull {
        /// Tasks the pool holds.
        capacity: usize,
        /// Tasks the run asked for when it stopped inserting.
        asked: usize,
    },
    /// A shadow pass was given unusable settings or a G-buffer of the wrong size.
    #[error("invalid shadow pass input: {0}")]
    InvalidShadowInput(String),
}

/// `Result` with the crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
