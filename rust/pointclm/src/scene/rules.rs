//! [`SceneRules`]: every scene-wide rule of point-cloud registration, declared once.

use crate::config::Unit;

crate::config::config! {
    /// The scene-wide rules of point-cloud registration: how the voxel is chosen, which scan
    /// points are strays, when peeling goes on, when a scan is taken for a heap, which turned
    /// alternatives of a pose are tried and how poses are ranked against the scene's others.
    /// Each is declared once, here, with its default, unit and range; a length in voxels is
    /// unitless (a ratio to the voxel). The acceptance rules of one pose are
    /// [`crate::pointcloud::RefineParams`]'.
    #[derive(Debug, Clone, PartialEq)]
    pub struct SceneRules {
        /// The default voxel is the model's bounding-box diagonal over this: about 1,500
        /// points on a typical object whatever its units, and an FPFH radius (5 voxels) of
        /// 1/8 of its size.
        pub voxels_per_diagonal: f64 = 40.0 => Unit::Unitless, [1.0, 1e6];
        /// The voxel is at least this many times the scan's point spacing (median distance to
        /// the nearest other point): a voxel finer than the sensor's sampling leaves holes in
        /// the downsampled scan, and the normal and FPFH radii then hold too few points.
        /// Chosen on the realistic validation scenes thinned to 30 % and 10 % of their points
        /// (F1 0.38 and 0 with the model's voxel, 0.56 and 0.25 with sqrt 2 spacings).
        pub min_voxel_spacings: f64 = 1.4 => Unit::Unitless, [0.0, 1e3];
        /// The voxel is at least this many times the scan's noise (standard deviation about
        /// its surface): normals are fitted over 2 voxels, and noise above a fifth of that
        /// radius turns them, and FPFH with them, at random.
        pub min_voxel_noises: f64 = 2.5 => Unit::Unitless, [0.0, 1e3];
        /// The scan's noise is estimated at this many model voxels (the normals' scale).
        pub noise_scale_voxels: f64 = 2.0 => Unit::Unitless, [1e-3, 1e3];
        /// A downsampled scan point with fewer than this many others within the normals'
        /// radius (2 voxels) is a stray (a flying pixel, multipath): it cannot fit a plane,
        /// where a surface gives each point about 12.
        pub stray_neighbours: usize = 3 => Unit::Unitless, [0, 1000];
        /// Strays are dropped only when they are more than this share of the scan; below it
        /// the scan is left as it is (real scans have isolated surface points too: 0.01-0.1 %
        /// on the realistic benchmark's, about 3 % on the bins'). Strays up to 5 % cost
        /// nothing on the validation sets, 10 % and 20 % cost a fifth of the F1 unless
        /// dropped.
        pub max_stray_share: f64 = 0.05 => Unit::Unitless, [0.0, 1.0];
        /// A scan reaching beyond this many model radii from its centroid is a scene
        /// (surfaces behind the copies), whose own occlusions tell the side its sensor stood
        /// on: more than one copy's extent, so that one object alone never counts.
        pub scene_extent: f64 = 2.0 => Unit::Unitless, [0.0, 1e6];
        /// Peeling: a scan point within this many voxels of an accepted copy's posed model is
        /// explained (the fitness radius, 1.5 voxels, plus the scan's noise at edges).
        pub peel_radius_voxels: f64 = 2.0 => Unit::Unitless, [1e-3, 1e3];
        /// Peeling stops after this many rounds (each round must add a copy to go on; a bin
        /// of 80 parts with about half visible needs a few rounds of several copies each).
        pub max_peel_rounds: usize = 20 => Unit::Unitless, [0, 1000];
        /// Once a pass matches as in a heap, peeling stops only after this many rounds in a
        /// row add no copy (elsewhere after one): each round samples its matches and its
        /// RANSAC anew, and in a heap an empty round is often the luck of the draw. On the
        /// validation bins 1, 2 and 3 found 0.425, 0.462 and 0.470 of the half-visible copies
        /// in 1, 1.08 and 1.15 times the time.
        pub heap_empty_rounds: usize = 2 => Unit::Unitless, [1, 1000];
        /// Once peeling has accepted this many copies, the scan is taken for a heap of
        /// identical parts and later passes relax the mutual check. Chosen on the validation
        /// sets: realistic scenes (2 to 8 copies among clutter) accept at most 7; on the
        /// validation bins 8, 10 and 12 found the same share of half-visible copies. On the
        /// validation matrix 3 and 1 find more copies in piles of curved parts (the narrow far
        /// camera, the dragon, the rocker arm) and add wrong poses in the room, time-of-flight,
        /// box-pile and bracket cells; no value is within 0.03 F1 of the best on every cell
        /// (benchmarks/results/matrix/heap_switch.md).
        pub heap_min_copies: usize = 10 => Unit::Unitless, [1, 1_000_000];
        /// The windowed mutual check's cube side in model diagonals for a heap
        /// (`mutual_window="auto"`): the best of the sizes tried on the validation bins.
        pub heap_window: f64 = 2.0 => Unit::Unitless, [1e-3, 1e6];
        /// In a scan said to be a heap, each peeling round also proposes this many poses by
        /// voting with point pair features over the unexplained scan points: in a heap FPFH's
        /// radius takes in the neighbouring copies, while two points of one copy give the
        /// model's pair feature whatever lies around it. On the validation bins 40 / 100 a
        /// round raised the recall of half-visible copies 0.676 -> 0.852 / 0.885.
        pub heap_voted_poses: usize = 100 => Unit::Unitless, [0, 1_000_000];
        /// A voted pose is kept only if it explains at least this share of the model relative
        /// to the median copy accepted so far: a voted pose has no descriptor support, and a
        /// pose buried among the copies shows the sensor a fifth of the model. On the
        /// validation bins wrong voted poses explained 0.35 (median) of the median copy's
        /// share, right ones 0.83.
        pub voted_min_relative_fitness: f64 = 0.6 => Unit::Unitless, [0.0, 1.0];
        /// Model points (evenly strided) the screen of voted poses counts before ICP: a
        /// share of the model is known to a few hundredths.
        pub screen_points: usize = 500 => Unit::Unitless, [1, 1_000_000];
        /// With peeling, each pass clusters into at least as many groups as the normalised
        /// Laplacian has eigenvalues below this level (`Config::cluster_level`). Chosen on the
        /// validation models' bins (half-visible copies 56 -> 77 of 187) and realistic scenes
        /// (F1 0.39 -> 0.45).
        pub peel_cluster_level: f64 = 0.7 => Unit::Unitless, [1e-9, 2.0];
        /// With a viewpoint, a turn of the model is tried only when at least this share of
        /// the turned model lies farther than the fitness radius from the model: below it the
        /// turn maps the model onto itself as far as verification can tell. A bed turned end
        /// for end moves 1-4 % of it.
        pub min_flip_change: f64 = 0.01 => Unit::Unitless, [0.0, 1.0];
        /// `min_flip_change` for poses judged without a viewpoint: the share of the model
        /// explained cannot tell a change of a few percent from noise.
        pub min_flip_change_by_fitness: f64 = 0.05 => Unit::Unitless, [0.0, 1.0];
        /// A quarter turn about a principal axis is tried only when it moves at most this
        /// share of the model (a near-symmetry such as a box about its vertical axis).
        pub max_quarter_turn_change: f64 = 0.5 => Unit::Unitless, [0.0, 1.0];
        /// A turned alternative that is no surer still replaces a pose when it explains more
        /// than this many times as many of the points that tell the two apart (and more by
        /// `flip_evidence_sigmas`). On the validation bins the right turn explained 60-220
        /// such points where the pose explained 0-25.
        pub flip_evidence_ratio: f64 = 4.0 => Unit::Unitless, [1.0, 1e6];
        /// See `flip_evidence_ratio`: the alternative's count must exceed the pose's by this
        /// many times the square root of their sum (a sign test at about three sigmas).
        pub flip_evidence_sigmas: f64 = 3.0 => Unit::Unitless, [0.0, 1e3];
        /// The scene's own alternatives (rotations of the duplicates peeling dropped, relative
        /// to the copy they lie on) are grouped within this many degrees: the benchmarks'
        /// rotation bound, within which two poses of a copy count as the same.
        pub scene_turn_deg: f64 = 15.0 => Unit::Unitless, [0.0, 180.0];
        /// At most this many of the scene's alternatives are tried, the most frequent first:
        /// as many as the principal-axis half turns (each costs one ICP per pose).
        pub max_scene_turns: usize = 3 => Unit::Unitless, [0, 1000];
        /// With a viewpoint, a pose whose visible side lies on the scan more loosely than this
        /// many times the scene's median pose's is dropped: copies of one object in one scan
        /// are sampled by one sensor and fit alike. Right poses reached 1.12 times the median
        /// on the realistic validation scenes and 1.33 in the validation bins, wrong poses far
        /// from any copy 1.15-1.76.
        pub max_relative_visible_rmse: f64 = 1.3 => Unit::Unitless, [1.0, 1e6];
        /// The scene-wide comparisons (`max_relative_visible_rmse`, the tightness and
        /// stability factors) need at least this many poses: with two, the median is their
        /// mean and says nothing about which is off.
        pub min_poses_to_compare: usize = 3 => Unit::Unitless, [1, 1_000_000];
        /// `proposals="auto"` proposes poses from flat faces when at least this share of the
        /// downsampled model lies in planar faces wide enough to hold a whole FPFH
        /// neighbourhood (a disc of the descriptor's radius, 5 voxels): there every point's
        /// descriptor is the same flat one, and the model is mostly such faces from half on.
        /// Measured: the matrix's boxes 0.89-0.99, the bracket 0.99, the fandisk 0.43, the
        /// rocker arm 0.16, the bunny 0.03, the dragon 0.00.
        pub min_planar_share: f64 = 0.5 => Unit::Unitless, [0.0, 1.0];
        /// Face proposals per pass refined and verified, those the most of the model already
        /// lies on first (each costs one ICP; a face of a copy gives a handful of distinct
        /// placements, a dozen copies show about as many patches).
        pub max_face_poses: usize = 48 => Unit::Unitless, [0, 1_000_000];
    }
}
