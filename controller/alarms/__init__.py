"""Alarms as ISA-18.2 / IEC 62682 describe them (docs/plant-integration.md): the conditions
heliocal watches (:mod:`conditions`), an alarm's states and what changes them (:mod:`states`),
what orchestration raises them through (:mod:`sink`, handed in by the interface layer) and the
watcher that turns a campaign's and a night's outcomes into alarms (:mod:`watch`)."""
