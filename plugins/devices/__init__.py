"""Built-in device plugins: cast_gimbal, gripper6 (CiA 402 over CAN), mavlink_vehicle."""
