// CURVE key files: what `mocapd keygen` writes reads back (and as pyzmq's zmq.auth would
// read it), secrets stay private, every malformed certificate is an error naming the file
// and line, and an allow-list directory yields its clients' public keys only.
#include "protocol/curve.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <zmq.hpp>

#include "tests/support/test_takes.hpp"

namespace mocapd::curve {
namespace {

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

TEST(CurveKeysTest, KeygenWritesAPublicAndAPrivateCertificateThatReadBack) {
  ASSERT_TRUE(Available());
  const std::string dir = testing::TempDir("curve_keygen");
  const KeyPair keys = GenerateKeyPair();
  EXPECT_TRUE(IsZ85Key(keys.public_key));
  EXPECT_EQ(PublicKeyOf(keys.secret_key), keys.public_key);
  WriteCertificates(dir + "/daemon", keys);
  const KeyPair public_half = ReadCertificate(dir + "/daemon.key", false);
  EXPECT_EQ(public_half.public_key, keys.public_key);
  EXPECT_TRUE(public_half.secret_key.empty());
  const KeyPair both = ReadCertificate(dir + "/daemon.key_secret", true);
  EXPECT_EQ(both.public_key, keys.public_key);
  EXPECT_EQ(both.secret_key, keys.secret_key);
  const auto perms = std::filesystem::status(dir + "/daemon.key_secret").permissions();
  EXPECT_EQ(perms & (std::filesystem::perms::group_all | std::filesystem::perms::others_all),
            std::filesystem::perms::none);
  // The public file never carries the secret.
  std::ifstream in(dir + "/daemon.key");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text.find(keys.secret_key), std::string::npos);
  EXPECT_NE(text.find("public-key = \"" + keys.public_key + "\""), std::string::npos);
  // An existing key is never overwritten.
  EXPECT_NE(ErrorOf([&] {
              WriteCertificates(dir + "/daemon", GenerateKeyPair());
            }).find("already exists"),
            std::string::npos);
  EXPECT_EQ(ReadCertificate(dir + "/daemon.key_secret", true).secret_key, keys.secret_key);
  // Nor is a public half written beside a secret one it would not match.
  std::filesystem::remove(dir + "/daemon.key");
  EXPECT_ANY_THROW(WriteCertificates(dir + "/daemon", GenerateKeyPair()));
  EXPECT_FALSE(std::filesystem::exists(dir + "/daemon.key"));
  // And never through a symlink (a dangling one would otherwise be written through).
  std::filesystem::create_symlink(dir + "/elsewhere", dir + "/linked.key_secret");
  EXPECT_ANY_THROW(WriteCertificates(dir + "/linked", GenerateKeyPair()));
  EXPECT_FALSE(std::filesystem::exists(dir + "/elsewhere"));
}

// `mocapd keygen --out keys/authorized/viewer` on a fresh clone: the directories are made;
// a path that names no key pair (empty, a directory, one with the extension already) is
// refused with what to give instead, before anything is written.
TEST(CurveKeysTest, KeygenMakesItsDirectoryAndRefusesPathsThatNameNoKeyPair) {
  const std::string dir = testing::TempDir("curve_keygen_paths");
  WriteCertificates(dir + "/keys/authorized/viewer", GenerateKeyPair());
  EXPECT_TRUE(std::filesystem::exists(dir + "/keys/authorized/viewer.key_secret"));
  for (const std::string& bad : {std::string(""), dir + "/keys/", dir + "/keys/x.key",
                                 dir + "/keys/x.key_secret", dir + "/keys/.hidden"})
    EXPECT_NE(
        ErrorOf([&] { WriteCertificates(bad, GenerateKeyPair()); }).find("without an extension"),
        std::string::npos)
        << "'" << bad << "'";
  EXPECT_FALSE(std::filesystem::exists(dir + "/keys/x.key.key"));
  EXPECT_FALSE(std::filesystem::exists(dir + "/keys/.key"));
  EXPECT_NE(ErrorOf([&] {
              ReadCertificate(dir + "/nowhere.key", false);
            }).find("No such file or directory"),
            std::string::npos);
}

TEST(CurveKeysTest, MalformedCertificatesAreErrorsNamingFileAndLine) {
  const std::string dir = testing::TempDir("curve_bad");
  const auto write = [&](const std::string& name, const std::string& text) {
    const std::string path = dir + "/" + name;
    std::ofstream(path) << text;
    std::filesystem::permissions(
        path, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
    return path;
  };
  const std::string short_key = write("short.key", "curve\n    public-key = \"abc\"\n");
  EXPECT_EQ(ErrorOf([&] { ReadCertificate(short_key, false); }),
            short_key + ":2: public-key is not a 40-character Z85 key");
  const std::string empty = write("empty.key", "# nothing\nmetadata\n");
  EXPECT_NE(ErrorOf([&] { ReadCertificate(empty, false); }).find(empty + ": no public-key"),
            std::string::npos);
  const KeyPair a = GenerateKeyPair(), b = GenerateKeyPair();
  const std::string mixed =
      write("mixed.key_secret", "curve\n    public-key = \"" + a.public_key +
                                    "\"\n    secret-key = \"" + b.secret_key + "\"\n");
  EXPECT_NE(ErrorOf([&] { ReadCertificate(mixed, true); }).find("does not belong to secret-key"),
            std::string::npos);
  const std::string only_public =
      write("public.key", "curve\n public-key = '" + a.public_key + "'\n");
  EXPECT_EQ(ReadCertificate(only_public, false).public_key, a.public_key);  // quotes: either kind
  EXPECT_NE(ErrorOf([&] { ReadCertificate(only_public, true); }).find("no secret-key"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { ReadCertificate(dir + "/missing.key", false); }).find("cannot read"),
            std::string::npos);
  // Both halves of a client's keys, or neither.
  EXPECT_FALSE(ReadClientKeys("", "", "replay").has_value());
  EXPECT_NE(ErrorOf([&] { ReadClientKeys("", only_public, "replay"); }).find("replay: CURVE needs"),
            std::string::npos);
}

TEST(CurveKeysTest, AnAllowListDirectoryYieldsItsPublicKeysSorted) {
  const std::string dir = testing::TempDir("curve_allow");
  const KeyPair b = GenerateKeyPair(), a = GenerateKeyPair();
  WriteCertificates(dir + "/b_viewer", b);
  WriteCertificates(dir + "/a_bridge", a);
  std::ofstream(dir + "/notes.txt") << "not a key";
  const std::vector<AuthorizedKey> keys = ReadAuthorizedKeys(dir);
  ASSERT_EQ(keys.size(), 2u);
  EXPECT_EQ(keys[0].public_key, a.public_key);
  EXPECT_EQ(keys[1].public_key, b.public_key);
  EXPECT_NE(keys[0].file.find("a_bridge.key"), std::string::npos);
  EXPECT_NE(ErrorOf([&] { ReadAuthorizedKeys(dir + "/none"); }).find("cannot list"),
            std::string::npos);
}

// The keys work on real sockets: a client that knows the server's key talks to it; one
// that has the wrong server key never gets a message through.
TEST(CurveKeysTest, AClientReachesOnlyTheServerWhoseKeyItHolds) {
  zmq::context_t context;
  const KeyPair server_keys = GenerateKeyPair(), client_keys = GenerateKeyPair();
  zmq::socket_t server(context, zmq::socket_type::pull), good(context, zmq::socket_type::push),
      wrong(context, zmq::socket_type::push);
  MakeServer(server, server_keys, "");
  server.bind("tcp://127.0.0.1:*");
  const std::string endpoint = server.get(zmq::sockopt::last_endpoint);
  for (zmq::socket_t* s : {&good, &wrong}) s->set(zmq::sockopt::linger, 0);
  MakeClient(wrong, client_keys, GenerateKeyPair().public_key);
  wrong.connect(endpoint);
  (void)wrong.send(zmq::str_buffer("forged"), zmq::send_flags::dontwait);
  MakeClient(good, client_keys, server_keys.public_key);
  good.connect(endpoint);
  (void)good.send(zmq::str_buffer("hello"), zmq::send_flags::none);
  server.set(zmq::sockopt::rcvtimeo, 5000);
  zmq::message_t message;
  ASSERT_TRUE(server.recv(message));
  EXPECT_EQ(message.to_string(), "hello");
  server.set(zmq::sockopt::rcvtimeo, 300);
  EXPECT_FALSE(server.recv(message));
}

}  // namespace
}  // namespace mocapd::curve
