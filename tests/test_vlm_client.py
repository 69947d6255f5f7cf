"""The VLM client against real HTTP servers started by the test on 127.0.0.1 (and a stand-in
urlopen for the failures a local server cannot cause on demand, such as a connect time-out)."""

import base64
import http.client
import http.server
import json
import socket
import threading
import time
import urllib.error

import numpy as np
import pytest

from kosmos_jax.annotators import vlm


def chat_reply(text):
    return json.dumps({"choices": [{"message": {"role": "assistant", "content": text}}]}).encode()


class Server:
    """An http.server in a thread; `script` is a list of (status, body, delay_s) answers in turn
    (the last one repeats); `requests` records each request's JSON."""

    def __init__(self, script):
        self.script = list(script)
        self.requests = []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_POST(self):
                body = self.rfile.read(int(self.headers["Content-Length"]))
                outer.requests.append({"path": self.path, "json": json.loads(body), "auth": self.headers.get("Authorization")})
                status, reply, delay = outer.script[min(len(outer.requests), len(outer.script)) - 1]
                time.sleep(delay)
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(reply)))
                    self.end_headers()
                    self.wfile.write(reply)
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()

    @property
    def url(self):
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"


IMAGE = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)


def client(server, tmp_path, **kw):
    sleeps = []
    options = dict(model="test-vlm", timeout_s=2.0, max_retries=2, backoff_s=0.05, cache_dir=tmp_path / "cache",
                   sleep=sleeps.append)
    options.update(kw)
    return vlm.VLMClient(server.url, **options), sleeps


def test_good_server_gets_the_image_and_prompt(tmp_path):
    with Server([(200, chat_reply('Sure. "Grasp the black and silver object."'), 0)]) as server:
        c, _ = client(server, tmp_path, api_key="k")
        assert c.sentence(IMAGE, "colour") == "Grasp the black and silver object."
        (request,) = server.requests
    assert request["path"] == "/v1/chat/completions" and request["auth"] == "Bearer k"
    body = request["json"]
    assert body["model"] == "test-vlm"
    text, image = body["messages"][0]["content"]
    assert text["text"] == vlm.PROMPTS["colour"]
    url = image["image_url"]["url"]
    assert url.startswith("data:image/png;base64,")
    png = base64.b64decode(url.split(",", 1)[1])
    assert png == vlm.encode_png(IMAGE)
    import cv2
    decoded = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(decoded, IMAGE)


def test_cache_hit_makes_no_second_request(tmp_path):
    with Server([(200, chat_reply("Grasp the object for writing."), 0)]) as server:
        c, _ = client(server, tmp_path)
        first = c.sentence(IMAGE, "purpose")
        again = vlm.VLMClient(server.url, "test-vlm", cache_dir=tmp_path / "cache")  # a rebuild
        assert again.sentence(IMAGE, "purpose") == first == "Grasp the object for writing."
        assert len(server.requests) == 1 and again.calls == 0
        # another model (or prompt, or image) is another key
        other = vlm.VLMClient(server.url, "other-model", cache_dir=tmp_path / "cache")
        other.ask(IMAGE, vlm.PROMPTS["purpose"])
        assert len(server.requests) == 2


def test_500_then_success_is_retried_with_backoff(tmp_path):
    script = [(500, b"overloaded", 0), (503, b"busy", 0), (200, chat_reply("Grasp the mug."), 0)]
    with Server(script) as server:
        c, sleeps = client(server, tmp_path)
        assert c.sentence(IMAGE, "name") == "Grasp the mug."
        assert len(server.requests) == 3
    assert sleeps == [0.05, 0.1]  # exponential back-off


def test_timeouts_give_a_timeout_error_after_bounded_retries(tmp_path):
    with Server([(200, chat_reply("Grasp the mug."), 1.0)]) as server:
        c, sleeps = client(server, tmp_path, timeout_s=0.2, max_retries=1)
        start = time.monotonic()
        with pytest.raises(vlm.VLMTimeoutError, match=r"timed out after 0.2 s on all 2 tries"):
            c.sentence(IMAGE, "name")
        assert time.monotonic() - start < 1.5
        assert len(server.requests) == 2 and sleeps == [0.05]


def test_client_errors_are_not_retried(tmp_path):
    with Server([(401, b'{"error": "bad key"}', 0)]) as server:
        c, _ = client(server, tmp_path)
        with pytest.raises(vlm.VLMError, match=r"HTTP 401.*bad key"):
            c.sentence(IMAGE, "name")
        assert len(server.requests) == 1


def test_refused_connection_is_retried_then_reported(tmp_path):
    with Server([]) as server:
        url = server.url
    c = vlm.VLMClient(url, "m", max_retries=1, backoff_s=0.0, timeout_s=1.0)
    with pytest.raises(vlm.VLMError, match=r"failed .* on all 2 tries"):
        c.ask(IMAGE, "hello")
    assert c.calls == 2


class RawServer:
    """A bare TCP server on 127.0.0.1 that reads each request whole, then acts on the next entry of
    `script` (the last one repeats): "close" hangs up without a byte, "junk" answers bytes that are
    not HTTP, any bytes are sent as the whole HTTP reply."""

    def __init__(self, script):
        self.script = list(script)
        self.connections = 0
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/v1"
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _read_request(self, conn):
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = conn.recv(65536)
            if not chunk:
                return
            data += chunk
        head, body = data.split(b"\r\n\r\n", 1)
        length = next(int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length"))
        while len(body) < length:
            body += conn.recv(65536)

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:  # closed by __exit__
                return
            with conn:
                self.connections += 1
                action = self.script[min(self.connections, len(self.script)) - 1]
                self._read_request(conn)
                if action == "junk":
                    conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\nnot http at all\r\n")
                elif action != "close":
                    conn.sendall(action)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.sock.close()


def http_ok(body):
    return b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: %d\r\nConnection: close\r\n\r\n%s" % (
        len(body), body)


@pytest.mark.parametrize("failure", ["close", "junk"])
def test_broken_answer_then_success_is_retried(tmp_path, failure):
    with RawServer([failure, failure, http_ok(chat_reply("Grasp the mug."))]) as server:
        c, sleeps = client(server, tmp_path)
        assert c.sentence(IMAGE, "name") == "Grasp the mug."
        assert server.connections == 3 and c.calls == 3
    assert sleeps == [0.05, 0.1]


@pytest.mark.parametrize("failure, cause", [("close", "RemoteDisconnected"), ("junk", "BadStatusLine")])
def test_broken_answers_every_time_are_a_vlm_error_naming_the_url(tmp_path, failure, cause):
    with RawServer([failure]) as server:
        c, sleeps = client(server, tmp_path)
        with pytest.raises(vlm.VLMError) as raised:
            c.sentence(IMAGE, "name")
        assert server.connections == 3
    message = str(raised.value)
    assert message.startswith(server.url + "/chat/completions failed (") and cause in message
    assert message.endswith("on all 3 tries") and not isinstance(raised.value, vlm.VLMTimeoutError)
    assert sleeps == [0.05, 0.1]
    assert not list((tmp_path / "cache").rglob("*.json"))


@pytest.mark.parametrize("failure, timed_out", [
    (urllib.error.URLError(TimeoutError("timed out")), True),  # while connecting
    (TimeoutError("timed out"), True),  # while reading the reply
    (urllib.error.URLError(ConnectionRefusedError(111, "refused")), False),
    (ConnectionResetError(104, "reset"), False),
    (http.client.IncompleteRead(b"{"), False),
])
def test_transport_failures_are_retried_and_classified(monkeypatch, failure, timed_out):
    def urlopen(request, timeout):
        raise failure

    monkeypatch.setattr(vlm.urllib.request, "urlopen", urlopen)
    sleeps = []
    c = vlm.VLMClient("http://127.0.0.1:9/v1", "test-vlm", max_retries=2, backoff_s=0.05, sleep=sleeps.append)
    with pytest.raises(vlm.VLMError) as raised:
        c.ask(IMAGE, "prompt")
    assert isinstance(raised.value, vlm.VLMTimeoutError) == timed_out
    assert raised.value.__cause__ is failure and c.calls == 3 and sleeps == [0.05, 0.1]


@pytest.mark.parametrize("body, message", [
    (b"<html>502 Bad Gateway</html>", r"not a chat-completions response.*502 Bad Gateway"),
    (b'{"choices": []}', r"not a chat-completions response"),
    (chat_reply(""), r"without text content"),
    (chat_reply("I cannot help with that."), r"'colour' reply does not follow the requested format.*cannot help"),
])
def test_junk_replies_are_clear_errors_and_not_cached(tmp_path, body, message):
    with Server([(200, body, 0)]) as server:
        c, _ = client(server, tmp_path)
        with pytest.raises(vlm.VLMResponseError, match=message):
            c.sentence(IMAGE, "colour")
        assert len(server.requests) == 1
    cached = list((tmp_path / "cache").rglob("*.json"))
    # a well-formed reply off the format is cached (a rebuild repeats the error without a call);
    # a body that is not a chat-completions answer is not
    assert len(cached) == (1 if b"cannot help" in body else 0)


def test_parse_sentence_is_robust():
    assert vlm.parse_sentence("colour", 'The object is dark.\n\n**"Grasp the black object with silver details."**') == \
        "Grasp the black object with silver details."
    assert vlm.parse_sentence("part", "Answer: grasp the handle of the spoon.") == "Grasp the handle of the spoon."
    assert vlm.parse_sentence("strategy", "It is long. Grasp its middle.") == "It is long. Grasp its middle."
    content_parts = json.dumps({"choices": [{"message": {"content": [{"type": "text", "text": "Grasp the mug."}]}}]})
    assert vlm.reply_text(content_parts.encode()) == "Grasp the mug."


def test_annotate_builds_object_words(tmp_path):
    replies = {
        "Name the object": "Grasp the spoon.",
        "color recognition": "Grasp the silver object.",
        "shape adjectives": "Grasp the long and thin object.",
        "real-world purpose": "Grasp the object for eating soup.",
        "outline an effective strategy": "It is long. Grasp the handle. Close across it.",
        "rectangular grasp": "Grasp the handle of the spoon.",
    }

    class Fake(vlm.VLMClient):
        def ask(self, image, prompt):
            self.calls += 1
            return next(reply for key, reply in replies.items() if key in prompt)

    corners = np.array([[[0, 0], [4, 0], [4, 2], [0, 2]], [[5, 5], [9, 5], [9, 7], [5, 7]]], float)
    words = vlm.annotate(Fake("http://unused", "m"), IMAGE, corners)
    assert (words.name, words.colour, words.shape, words.purpose) == ("spoon", "silver", "long and thin", "eating soup")
    assert words.parts == ("handle", "handle")
    assert words.sentences["part"] == ("Grasp the handle of the spoon.",) * 2
