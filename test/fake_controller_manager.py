"""
A controller manager that answers ``list_controllers`` and ``switch_controller`` as ros2_control's.

Transcribed from ros2_control, branch jazzy, commit 9ffbf97fd,
controller_manager/src/controller_manager.cpp (``cm.cpp``), for a manager whose controllers
are all configured and chain nothing:

* strictness 0 takes the manager's default, ``best_effort``
  (controller_manager_parameters.yaml:52-62; cm.cpp:1903-1920); AUTO and FORCE_AUTO are
  taken as BEST_EFFORT (cm.cpp:1922-1937);
* an unknown name: STRICT fails with "... because no controller with this name exists";
  BEST_EFFORT fails only where no known name came before it in its list (cm.cpp:1962-2005);
* deactivating a controller that is not active: STRICT fails ("... can not be deactivated
  since it is not active."), BEST_EFFORT drops it (cm.cpp:2125-2170); activating an active
  one likewise (cm.cpp:2060-2120);
* nothing left to switch: ok, "After checking the controllers, no controllers need to be
  activated or deactivated." (cm.cpp:2176-2182).

Not modelled: unconfigured controllers, chains, a restart (one name in both lists), and the
hardware interfaces' conflicts.

Each controller is a node of its own name in the manager's namespace with its parameters
declared under their real names (cm.cpp:2470-2482: ``node_namespace`` is the manager's).
"""
from typing import Dict, List, Mapping

import rclpy

BEST_EFFORT, STRICT, AUTO, FORCE_AUTO = 1, 2, 3, 4
NOTHING = 'After checking the controllers, no controllers need to be activated or deactivated.'


class FakeControllerManager:
    """``controllers``: name -> (type, state, parameters); ``srv``, ``msg``: the built types."""

    def __init__(self, context, executor, srv, msg,
                 controllers: Mapping[str, tuple], namespace: str = '/',
                 name: str = 'controller_manager'):
        self.srv, self.msg = srv, msg
        self.node = rclpy.create_node(name, namespace=namespace, context=context)
        self.node.create_service(srv.ListControllers, '~/list_controllers', self._list)
        self.node.create_service(srv.SwitchController, '~/switch_controller', self._switch)
        self.types: Dict[str, str] = {}
        self.states: Dict[str, str] = {}
        self.nodes = [self.node]
        self.requests: List = []        # every switch request, in order
        for cname, (ctype, state, params) in controllers.items():
            self.types[cname], self.states[cname] = ctype, state
            node = rclpy.create_node(cname, namespace=namespace, context=context)
            for key, value in params.items():
                node.declare_parameter(key, value)
            self.nodes.append(node)
        for node in self.nodes:
            executor.add_node(node)

    def _list(self, request, response):
        response.controller = [
            self.msg.ControllerState(name=n, type=self.types[n], state=s, update_rate=500)
            for n, s in self.states.items()]
        return response

    def _switch(self, request, response):
        self.requests.append(request)
        strictness = request.strictness or BEST_EFFORT
        strict = strictness == STRICT
        chosen = {}
        for action, names in (('deactivate', request.deactivate_controllers),
                              ('activate', request.activate_controllers)):
            found, failed, said = [], False, ''
            for n in names:
                if n in self.states:
                    found.append(n)
                    failed = False
                    continue
                message = (f"Could not {action} controller with name '{n}' because no "
                           'controller with this name exists')
                if strict:
                    response.ok, response.message = False, message
                    return response
                failed, said = not found, said + message + '\n'
            if failed:
                response.ok, response.message = False, said
                return response
            chosen[action] = found
        for action, target in (('deactivate', 'active'), ('activate', 'inactive')):
            keep = []
            for n in chosen[action]:
                if self.states[n] == target:
                    keep.append(n)
                elif strict:
                    response.ok = False
                    response.message = (
                        f"Controller with name '{n}' can not be deactivated since it is not "
                        'active.' if action == 'deactivate' else
                        f"Controller with name '{n}' is already active.")
                    return response
            chosen[action] = keep
        if not chosen['deactivate'] and not chosen['activate']:
            response.ok, response.message = True, NOTHING
            return response
        for n in chosen['deactivate']:
            self.states[n] = 'inactive'
        for n in chosen['activate']:
            self.states[n] = 'active'
        response.ok, response.message = True, ''
        return response

    def destroy(self):
        """Destroy the manager's and the controllers' nodes."""
        for node in self.nodes:
            node.destroy_node()
