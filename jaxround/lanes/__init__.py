"""Lanes side by side: SUMO's LC2013 lane-change model in JAX.

`params` holds a vType's lane-change numbers (`LaneChangeParams`), `follow`
the car-following quantities the model asks of the IDM, `lc2013` one
vehicle's wish to change (`MSLCM_LC2013::_wantsChange` and its messages to
neighbours), `changer` the per-edge loop that decides and applies the
changes (`MSLaneChanger::laneChange`), and `road` a straight multi-lane road
that runs them with the IDM, the testbed against SUMO. `best_lanes` (numpy,
no JAX) builds SUMO's strategic lane table (`MSVehicle::updateBestLanes`) for
a roundabout's routes once per network.
"""
