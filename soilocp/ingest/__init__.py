"""Importers of real robots' logs (ROS 2 bags, CSV) into the sensor log."""
