"""The Sensor Manager on the wire: its registrar, its server, its service type and its equality.

Its server and every client (``interface.py``, the Context Manager) import this
module, never each other, so both sides share a sensor by one rule.
"""
from temoto_core.rr.deadlines import register_deadlines
from temoto_core.rr.keys import register_key
from temoto_sensor_manager.srv import LoadSensor

RR_NAME = 'temoto_sensor_manager'
START_SENSOR = 'start_sensor'
START_SENSOR_TYPE = LoadSensor
CATALOGUE = 'catalogue'            # a GetRegistry service: the catalogue and its reliabilities, as JSON


def sensor_key(request) -> tuple:
    """Equality of sensor requests, as the original: type, package, executable, output topics (a multiset).

    Input topics are left out: they do not change which device runs.
    """
    return (request.sensor_type.strip(), request.package_name.strip(), request.executable.strip(),
            tuple(sorted((kv.key, kv.value) for kv in request.output_topics)))


register_key(LoadSensor._request_class, sensor_key)
# The longest a load may take (deadlines.py): the driver's process start (15 s) and its first data (20 s at
# most by default); an unload stops the driver.
register_deadlines(LoadSensor._request_class, load=40.0, unload=15.0)
