"""
policy_node's client of ros2_control's controller manager: the arm controller, and its stop.

* :meth:`ControllerManagerClient.refusal`: configure's one line, or None;
* :meth:`ControllerManagerClient.controller`: the arm controller as
  :func:`pg_node.control.controller_check.refusal` takes it: its type and state from the
  manager's ``list_controllers``, its parameters from its own ``get_parameters`` (a controller
  is a node named as the controller in the manager's namespace, its parameter services on:
  ros2_control (jazzy 9ffbf97fd) controller_manager/src/controller_manager.cpp:2474-2479);
* :meth:`ControllerManagerClient.deactivate` and :meth:`~ControllerManagerClient.activate`:
  ``switch_controller``, then ``list_controllers`` to see that it took effect.

Every call waits at most ``timeout`` for the service and as long for the answer, and fails
with one line (:class:`ControllerManagerError`). The client spins a node of its own with an
executor of its own, so it can be called from inside another node's callback (configure,
an e-stop) without blocking that node's executor.

``controller_manager_msgs`` is not on PyPI: it is installed with ros2_control, wherever a
controller manager runs. It is imported when a client is made, not when this module is.
"""
from typing import Dict, List, Optional, Sequence, Tuple

from pg_node.control.controller_check import Controller, PARAMETERS, refusal
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import parameter_value_to_python


class ControllerManagerError(Exception):
    """A controller manager that is missing, silent, or that refused: one line saying which."""


def messages():
    """Return ``controller_manager_msgs.srv`` (ros2_control's), or raise one line."""
    try:
        from controller_manager_msgs import srv
    except ImportError as err:
        raise ControllerManagerError(
            f'controller_manager_msgs cannot be imported ({err}): it is installed with '
            'ros2_control (ros-jazzy-controller-manager-msgs); source that installation, or '
            'turn the controller manager supervision off') from None
    return srv


class ControllerManagerClient:
    """
    Calls to one controller manager, each bounded by ``timeout`` seconds.

    ``manager``: the manager's node, resolved as a service name in ``namespace`` (a relative
    name for a manager beside policy_node, ``/controller_manager`` at the root).
    """

    def __init__(self, context, manager: str, timeout: float, namespace: str = '/',
                 name: str = 'pg_node_controller_manager_client'):
        self.srv = messages()
        self.timeout = timeout
        self.node = rclpy.create_node(name, context=context, namespace=namespace,
                                      use_global_arguments=False,
                                      start_parameter_services=False, enable_rosout=False)
        self.manager = self.node.resolve_service_name(manager)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._clients = {}

    def controller_path(self, name: str) -> str:
        """Return the full name of controller ``name``'s node: in the manager's namespace."""
        namespace = self.manager.rsplit('/', 1)[0]
        return f'{namespace}/{name}'

    def _call(self, srv_type, service: str, request):
        """Call ``service`` and return its response, within the timeouts, or raise one line."""
        client = self._clients.get(service)
        if client is None:
            client = self._clients[service] = self.node.create_client(srv_type, service)
        if not client.wait_for_service(timeout_sec=self.timeout):
            raise ControllerManagerError(f'no service {service} within {self.timeout:g} s')
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=self.timeout)
        if not future.done():
            client.remove_pending_request(future)
            raise ControllerManagerError(f'{service} did not answer within {self.timeout:g} s')
        return future.result()

    def list_controllers(self) -> List[Dict]:
        """Return the manager's controllers: name, type, state and their interfaces."""
        response = self._call(self.srv.ListControllers, f'{self.manager}/list_controllers',
                              self.srv.ListControllers.Request())
        return [{'name': c.name, 'type': c.type, 'state': c.state,
                 'claimed_interfaces': list(c.claimed_interfaces),
                 'required_command_interfaces': list(c.required_command_interfaces),
                 'required_state_interfaces': list(c.required_state_interfaces)}
                for c in response.controller]

    def state(self, name: str) -> Dict:
        """Return controller ``name``'s entry in ``list_controllers``, or raise one line."""
        listed = self.list_controllers()
        for entry in listed:
            if entry['name'] == name:
                return entry
        raise ControllerManagerError(
            f'{self.manager} has no controller {name} (it has: '
            f'{", ".join(c["name"] for c in listed) or "none"})')

    def parameters(self, node: str, names: Sequence[str]) -> Dict[str, object]:
        """
        Return those of the parameters ``names`` that node ``node`` declares, as Python values.

        A ``get_parameters`` that names one undeclared parameter answers nothing at all
        (rclpy and rclcpp alike), so ``list_parameters`` says first which ones it has.
        """
        listed = self._call(ListParameters, f'{node}/list_parameters',
                            ListParameters.Request(depth=ListParameters.Request.DEPTH_RECURSIVE))
        have = [n for n in names if n in set(listed.result.names)]
        if not have:
            return {}
        response = self._call(GetParameters, f'{node}/get_parameters',
                              GetParameters.Request(names=have))
        return {n: parameter_value_to_python(v) for n, v in zip(have, response.values)
                if v.type != ParameterType.PARAMETER_NOT_SET}

    def controller(self, name: str) -> Controller:
        """Return controller ``name`` as the manager lists it, with its parameters."""
        entry = self.state(name)
        path = self.controller_path(name)
        params = self.parameters(path, PARAMETERS)
        gains = Controller(name, '', '', params).gain_names()
        if gains:
            params.update(self.parameters(path, gains))
        return Controller(name, entry['type'], entry['state'], params, path)

    def refusal(self, name: str, interface: str, command_message: str,
                allow_no_dead_man: bool = False, controller_hold: str = 'none'
                ) -> Optional[str]:
        """
        Return why configure refuses controller ``name`` for the card's commands, or None.

        A manager or controller that cannot be read is a refusal too: the supervision was
        asked for, and nothing proves the set-up safe.
        """
        try:
            ctrl = self.controller(name)
        except ControllerManagerError as err:
            return f'cannot check controller {name} through {self.manager}: {err}'
        return refusal(ctrl, interface, command_message, allow_no_dead_man, controller_hold)

    def switch(self, activate: Sequence[str] = (), deactivate: Sequence[str] = (),
               strict: bool = False) -> Tuple[bool, str]:
        """
        Ask the manager to switch controllers; return its ``ok`` and ``message``.

        BEST_EFFORT unless ``strict``: a controller already in the asked state is no error
        (ros2_control (jazzy 9ffbf97fd) controller_manager.cpp:2134-2182); an unknown name
        is, in both (cm.cpp:1977-1993). ``timeout`` goes in the request too: the manager
        aborts a switch it cannot make in that time.
        """
        req = self.srv.SwitchController.Request(
            activate_controllers=list(activate), deactivate_controllers=list(deactivate),
            strictness=(self.srv.SwitchController.Request.STRICT if strict
                        else self.srv.SwitchController.Request.BEST_EFFORT),
            activate_asap=False)
        req.timeout.sec = int(self.timeout)
        req.timeout.nanosec = int((self.timeout % 1.0) * 1e9)
        response = self._call(self.srv.SwitchController, f'{self.manager}/switch_controller',
                              req)
        return response.ok, response.message

    def _switch_to(self, name: str, state: str) -> Optional[str]:
        """Switch ``name`` to ``state``; return None once the list shows it, else one line."""
        try:
            ok, message = self.switch(**{'activate' if state == 'active' else 'deactivate':
                                         [name]})
            now = self.state(name)['state']
        except ControllerManagerError as err:
            return str(err)
        if now != state:
            return (f'{self.manager} did not make {name} {state} (it is {now}; switch_controller '
                    f'said ok={ok}: {message or "no message"})')
        return None

    def deactivate(self, name: str) -> Optional[str]:
        """Deactivate controller ``name`` (the robot's own stop acts); None once it is inactive."""
        return self._switch_to(name, 'inactive')

    def activate(self, name: str) -> Optional[str]:
        """Activate controller ``name`` again (an explicit reset); None once it is active."""
        return self._switch_to(name, 'active')

    def close(self):
        """Destroy the client's node and executor."""
        self.executor.shutdown()
        self.node.destroy_node()
