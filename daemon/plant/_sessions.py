"""The OPC UA sessions of the plant: asyncua's ``InternalServer`` and ``InternalSession`` subclassed at their public
methods (``create_session``, ``activate_session``, ``create_subscription``, ``close_session``, ``register_server``)
to hold the rules that asyncua leaves to the application:

- **An identity only over Sign & Encrypt.** A session is activated only on a channel with a client certificate —
  with the relay (``_front``) in front, that is a Basic256Sha256 or Aes256Sha256RsaPss channel in SignAndEncrypt
  mode — and only with the certificate it was created with (``BadSecurityModeInsufficient``,
  ``BadSecurityChecksFailed``). A session needs the client's certificate from the start (``BadCertificateInvalid``).
- **A user name token names a user**: one without a user name is refused (``BadIdentityTokenInvalid``), after the
  cost of a password check (``PlantUsers.spend``) like every other failed login.
- **Failed logins per client**: after ``login_failures`` within ``login_window_s`` from one address, that address's
  activations are refused (``BadUserAccessDenied``) without a check until the window has passed.
- **Limits**: sessions (``BadTooManySessions``) and subscriptions (``BadTooManySubscriptions``) per client address
  and in total; a session not activated within ``activation_timeout_s`` is closed; the session timeout a client asks
  for is held to ``session_timeout_s``.
- **Discovery registration refused** (RegisterServer, RegisterServer2: ``BadServiceUnsupported``).
- **Only the methods that read may be called**: ConditionRefresh and ConditionRefresh2 (of the session's own
  subscriptions: another's is ``BadSubscriptionIdInvalid``) and the result-access methods of ``_result_access``;
  every other method — those that change the machine's state (Halt, Reset, StartSingleJob, PrepareRecipe, ...) and
  an alarm's Acknowledge, Confirm, Enable, Disable, AddComment — is answered ``BadUserAccessDenied``.

Every refusal is counted by ``_refusals``, not logged one by one.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any, NoReturn

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.internal_session import InternalSession, SessionState

from monoguide.daemon.plant._access import PlantUsers
from monoguide.daemon.plant._front import Front
from monoguide.daemon.plant._logins import LoginGate
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._settings import PlantLimits

# why asyncua refused a session, as the log and the metric count it
REASONS = {
    ua.StatusCodes.BadCertificateUntrusted: "a client certificate not in the trust list",
    ua.StatusCodes.BadCertificateUriInvalid: "an ApplicationUri other than its certificate's",
    ua.StatusCodes.BadUserAccessDenied: "a wrong user name or password",
    ua.StatusCodes.BadIdentityTokenRejected: "an identity token type not offered",
    ua.StatusCodes.BadIdentityTokenInvalid: "a malformed identity token",
}


REFRESH_METHODS = (ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                   ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh2))


class PlantServer(InternalServer):
    """asyncua's internal server with the plant's sessions."""

    def __init__(self, users: PlantUsers, front: Front, limits: PlantLimits, refusals: Refusals) -> None:
        super().__init__(user_manager=users)  # type: ignore[arg-type]
        self.users, self.front, self.limits, self.refusals = users, front, limits, refusals
        self.logins = LoginGate(limits.login_failures, limits.login_window_s)
        self.plant_sessions: dict[ua.NodeId, PlantSession] = {}
        self.max_session_timeout_ms = limits.session_timeout_s * 1000.0
        self.max_pending_activation_seconds = limits.activation_timeout_s
        self.max_subscriptions = limits.subscriptions
        self.max_connections = limits.connections + 1  # one from the relay per client connection it admits
        self.bind_condition_methods = True  # asyncua's ConditionRefresh (and 2) on ConditionType
        self.callable_methods: set[ua.NodeId] = set(REFRESH_METHODS)

    def create_session(self, name: Any, user: User | None = None, external: bool = False) -> InternalSession:
        if not external:
            return super().create_session(name, user or User(role=UserRole.Anonymous), external)
        client = self.front.client_of(name)
        if client is None:
            self.refusals.refuse("opcua", "a connection not through the plant's port", str(name))
            raise ServiceError(ua.StatusCodes.BadSecurityChecksFailed)
        if len(self.plant_sessions) >= self.limits.sessions:
            self.refuse(client, "max_sessions reached", ua.StatusCodes.BadTooManySessions)
        if sum(s.client == client for s in self.plant_sessions.values()) >= self.limits.sessions_per_client:
            self.refuse(client, "max_sessions_per_client reached", ua.StatusCodes.BadTooManySessions)
        session = PlantSession(self, client, name)
        self.plant_sessions[session.session_id] = session
        return session

    def forget(self, session: PlantSession) -> None:
        self.plant_sessions.pop(session.session_id, None)

    def subscriptions(self, client: str) -> tuple[int, int]:
        """The live subscriptions of ``client``'s sessions, and of all sessions."""
        theirs = {s.session_id for s in self.plant_sessions.values() if s.client == client}
        everyone = list(self.subscription_service.subscriptions.values())
        return sum(sub.session_id in theirs for sub in everyone), len(everyone)

    def refuse(self, client: str, reason: str, status: int) -> NoReturn:
        """Count the refusal and raise it to asyncua, which answers the request with ``status``."""
        self.refusals.refuse("opcua", reason, client)
        raise ServiceError(status)

    def register_server(self, server: Any, conf: Any = None) -> None:
        raise ServiceError(ua.StatusCodes.BadServiceUnsupported)

    def register_server2(self, params: ua.RegisterServer2Parameters) -> None:
        raise ServiceError(ua.StatusCodes.BadServiceUnsupported)


class PlantSession(InternalSession):
    """One client's session; ``client``: its IP address (from the relay)."""

    def __init__(self, server: PlantServer, client: str, name: Any) -> None:
        super().__init__(server, server.aspace, server.subscription_service, name, external=True)
        self.plant, self.client = server, client
        self.certificate: bytes | None = None  # the client's, from CreateSession
        self._deadline: asyncio.TimerHandle | None = None
        self._expiry: asyncio.Task[None] | None = None

    async def create_session(self, params: ua.CreateSessionParameters,
                             sockname: tuple[str, int] | None = None) -> ua.CreateSessionResult:
        plant = self.plant
        if not params.ClientCertificate:
            plant.refuse(self.client, "a session without a client certificate", ua.StatusCodes.BadCertificateInvalid)
        self.certificate = bytes(params.ClientCertificate)
        try:
            result = await super().create_session(params, sockname)
        except ServiceError as error:
            plant.refuse(self.client, REASONS.get(error.code, "a session refused"), error.code)
        self._deadline = asyncio.get_running_loop().call_later(plant.limits.activation_timeout_s, self._expire)
        return result

    def activate_session(self, params: ua.ActivateSessionParameters,
                         peer_certificate: bytes | None) -> ua.ActivateSessionResult:
        plant = self.plant
        if peer_certificate is None:
            plant.refuse(self.client, "a session over a channel without security",
                         ua.StatusCodes.BadSecurityModeInsufficient)
        if bytes(peer_certificate) != self.certificate:
            plant.refuse(self.client, "a channel certificate other than the session's",
                         ua.StatusCodes.BadSecurityChecksFailed)
        if plant.logins.waiting(self.client):
            plant.refuse(self.client, "login_failures reached", ua.StatusCodes.BadUserAccessDenied)
        token = params.UserIdentityToken
        if isinstance(token, ua.UserNameIdentityToken) and not token.UserName:
            plant.users.spend()
            plant.logins.failed(self.client)
            plant.refuse(self.client, "a user name token without a user name", ua.StatusCodes.BadIdentityTokenInvalid)
        try:
            return super().activate_session(params, peer_certificate)
        except ServiceError as error:
            if error.code in REASONS:
                plant.logins.failed(self.client)
            plant.refuse(self.client, REASONS.get(error.code, "an activation refused"), error.code)

    async def create_subscription(self, params: ua.CreateSubscriptionParameters, callback: Callable[..., Any],
                                  request_callback: Callable[..., Any] | None = None) -> ua.CreateSubscriptionResult:
        plant = self.plant
        theirs, everyone = plant.subscriptions(self.client)
        if everyone >= plant.limits.subscriptions:
            plant.refuse(self.client, "max_subscriptions reached", ua.StatusCodes.BadTooManySubscriptions)
        if theirs >= plant.limits.subscriptions_per_client:
            plant.refuse(self.client, "max_subscriptions_per_client reached", ua.StatusCodes.BadTooManySubscriptions)
        return await super().create_subscription(params, callback, request_callback)

    async def call(self, params: list[ua.CallMethodRequest]) -> list[ua.CallMethodResult]:
        """The methods that read; every other one refused, each in its own result."""
        plant = self.plant
        answers: list[ua.CallMethodResult | None] = []
        allowed = []
        for request in params:
            refusal = None
            if request.MethodId not in plant.callable_methods:
                refusal = ua.StatusCodes.BadUserAccessDenied
                plant.refusals.refuse("opcua", "a method that is not read-only", self.client)
            elif request.MethodId in REFRESH_METHODS and not self._owns(request.InputArguments):
                refusal = ua.StatusCodes.BadSubscriptionIdInvalid
            answers.append(None if refusal is None else ua.CallMethodResult(StatusCode=ua.StatusCode(refusal)))
            if refusal is None:
                allowed.append(request)
        results = iter(await super().call(allowed) if allowed else [])
        return [answer if answer is not None else next(results) for answer in answers]

    async def close_session(self, delete_subs: bool = True) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        try:
            await super().close_session(delete_subs)
        finally:
            self.plant.forget(self)

    def _owns(self, arguments: list[ua.Variant] | None) -> bool:
        """Whether the subscription a ConditionRefresh names is one of this session's."""
        if not arguments:
            return False
        subscription = self.plant.subscription_service.subscriptions.get(arguments[0].Value)
        return subscription is not None and subscription.session_id == self.session_id

    def _expire(self) -> None:
        if self.state == SessionState.Created:  # never activated: closed, its place freed
            self._expiry = asyncio.get_running_loop().create_task(self.close_session(True))
