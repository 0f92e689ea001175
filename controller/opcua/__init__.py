"""``heliocal opcua``: the OPC UA server (IEC 62541, asyncua) through which the plant's control
system sees the field, the night and the alarms and calls a few checked methods
(docs/plant-integration.md, "OPC UA")."""
