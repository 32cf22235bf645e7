"""The simulated LiDAR (docs/design.md §10a): ``simulate.simulate`` / ``simulate.sweep_for_frame`` cast a sweep of a
``core.lidar_model`` sensor over the scene the cameras see; ``sweep`` holds the returns, the objects' point counts
and nuScenes' ``.pcd.bin``; ``cast`` the rule and its float64 reference, ``cast_cpu`` the numba fast path."""
