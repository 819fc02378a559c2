"""Other libraries' objects in and out of pointclm, each imported only when the caller holds
one of its objects (:mod:`pointclm.interop.open3d`)."""
