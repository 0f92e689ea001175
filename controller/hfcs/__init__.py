"""The interface to the heliostat field control system (HFCS) that tracks the sun all day: the
tracking table (:mod:`tracking_table`) and the models with their versions (:mod:`models`);
docs/plant-integration.md, "The HFCS interface"."""
