//! The host-sized stages `strata slice` and admission control run models through: room for
//! any model the host can stream (megabytes: build them in a `Box` on a thread with a large
//! stack).

strata::slicer_type! {
    /// The host's slicer.
    pub type HostSlicer = {
        active_triangles: 1 << 17,
        contour_points: 1 << 17,
        contour_loops: 1 << 14,
    };
}

strata::toolpath_type! {
    /// The host's toolpath stage (about 20 MB).
    pub type HostToolpath = {
        toolpath_points: 1 << 16,
        toolpath_loops: 1 << 12,
        scan_crossings: 1 << 16,
        path_points: 1 << 18,
        window_ring_words: 1 << 18,
        window_spans: 1 << 17,
    };
}

strata::scratch_type! {
    /// The scratch both take turns in.
    pub type HostScratch = {
        contour_points: 1 << 17,
        toolpath_points: 1 << 16,
        scan_crossings: 1 << 16,
    };
}
