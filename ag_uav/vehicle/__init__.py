"""The vehicle and its sensors: the MuJoCo model (MJCF), the flight-controller cascade, the GNSS
receiver presets, the MEMS IMU and the batched sensor kernels the engine steps. (The radar
altimeter and the bearing sensor are drawn by the feedbacks that fuse them, in
:mod:`ag_uav.navigation`.)"""
