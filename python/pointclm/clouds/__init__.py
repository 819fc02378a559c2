"""What :func:`pointclm.register_point_clouds` needs around the Rust core's scene pipeline: the
call and its answer as a result (:mod:`.core_path`), the scene's voxel and the warning of a
disputed viewpoint (:mod:`.sensor`), the diagnosis of an empty or doubtful result
(:mod:`.diagnosis`), and the results (:mod:`.results`); :mod:`pointclm.point_clouds` holds the
one-call function.
"""
