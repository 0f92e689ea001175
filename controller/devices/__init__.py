"""Device drivers: actuator drives (serial, Modbus) and double-CCD cameras."""
